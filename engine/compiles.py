"""Whether numba compiled while something ran: a frame whose time includes compiling kernels is
not a rendering time (its stats say so, and medians and plots leave it out).

numba broadcasts a ``numba:compile`` event when a dispatcher really compiles (not when it loads
from the on-disk cache); :class:`CompileWatch` counts them from any thread, and also knows a
compile that was under way when it began or ended (the build's parallel kernels compiling in the
background, gridrt.trace.twin, while the serial strategy stands in for them).

:func:`inner` compiles a kernel that only other kernels call: numba then makes no entry point
from Python for it (its argument unboxing and result boxing, about a tenth of a cold start's
compile), and a call from Python is refused with a clear error instead.  Nor is it compiled to
machine code of its own (:class:`_InnerLibrary`): its callers link in its LLVM IR, as numba has
them do, and compile that.

:func:`one_per_types` keeps a kernel called from other kernels to one compile per argument types.
Two more ways a kernel compiles twice for the same work, avoided where kernels call kernels:
* a parallel loop's index is an int64 in numba's first typing of the loop and a uint64 in the
  parallel function made of it, so a kernel given the index compiles for both; kernels pass
  ``np.int64(i)``;
* numba types a read-only array apart from a writable one; a record whose arrays may come from
  either (a file's buffer, an array made here) gets read-only views of all of them.

A gridrt kernel loaded from numba's on-disk cache skips numba's full refresh of its compiler
contexts (see :func:`_load_ready`): a warm start compiles nothing, so it needs the runtime the
machine code links against, not the registries of every numba extension for typing and lowering.

Three steps of numba's compiler do work whose result they then drop; they are made to skip it
(:func:`_install_cheaper_frontend`), for every function numba compiles in the process, with the
same results: the deep copy of an inlined function's IR, the typing of an operator on scalars by
NumPy's array-operator rules, and the comparison of two sets of compiler flags through full
dicts of every option's value."""

import copy
import threading
import weakref

from llvmlite import binding as ll
from numba import njit
from numba.core import caching, event, targetconfig, typed_passes, types
from numba.core.codegen import JITCodeLibrary, JITCPUCodegen
from numba.core.registry import CPUDispatcher
from numba.core.runtime import rtsys


class _Counter(event.Listener):
    """Compiles started and under way in this process, from any thread."""

    def __init__(self):
        self.lock = threading.Lock()
        self.started = 0
        self.under_way = 0

    def on_start(self, ev):
        _install_cheaper_frontend()  # (numba compiles under its compiler lock: one thread at a time)
        with self.lock:
            self.started += 1
            self.under_way += 1

    def on_end(self, ev):
        with self.lock:
            self.under_way = max(0, self.under_way - 1)


_COUNTER = _Counter()
event.register("numba:compile", _COUNTER)


class CompileWatch:
    """``with CompileWatch() as w: ...``; then ``w.compiled`` is True when numba compiled during the
    block, or had a compile under way when it began or ended."""

    def __init__(self):
        self.compiled = False

    def __enter__(self):
        with _COUNTER.lock:
            self._started = _COUNTER.started
            self._busy = _COUNTER.under_way > 0
        return self

    def check(self):
        """Whether numba compiled since the block began (or had a compile under way then or now)."""
        with _COUNTER.lock:
            self.compiled = self._busy or _COUNTER.under_way > 0 or _COUNTER.started != self._started
        return self.compiled

    def __exit__(self, *exc):
        self.check()
        return False


def one_per_types(dispatcher):
    """Decorate a jitted function (above ``@njit``) so that a call from another jitted function
    compiles it for the argument types alone, not for the literal values given.

    numba types a constant argument (``f(x, True)``, ``f(x, 0)``, a module constant) as a literal
    and compiles the callee once per literal value it is called with; for a traversal called with
    any_hit True from the shading and False from the camera rays, that is two compiles of several
    seconds each, of one and the same code (a flag that stays a run-time value costs a predictable
    branch).  Calls from Python are not affected (numba never makes their arguments literal).
    """
    base = dispatcher.get_call_template

    def get_call_template(args, kws):
        return base(tuple(types.unliteral(a) for a in args), {k: types.unliteral(v) for k, v in kws.items()})

    dispatcher.get_call_template = get_call_template
    return dispatcher


class InnerDispatcher(CPUDispatcher):
    """The dispatcher of an :func:`inner` kernel: called from jitted code as any other, and
    refusing a call from Python (it has no Python entry point to call)."""

    def enable_caching(self):
        self._cache = _InnerCache(self.py_func)

    def __call__(self, *args, **kwargs):
        fn = self.py_func
        raise TypeError(f"{fn.__module__}.{fn.__qualname__} is a kernel that only other kernels call "
                        "(it is compiled without an entry point from Python): call it from a jitted "
                        "function")


def inner(*args, **options):
    """``@inner(cache=True, ...)`` (numba.njit's options) for a kernel that only other kernels call.

    numba compiles every jitted function with a CPython wrapper (unboxing each argument from a
    Python object, boxing the result) and a C wrapper, whether or not anything calls it from
    Python; for a helper taking a grid record and a few tuples, that wrapper is lowered, optimised
    and machine-compiled for nothing.  Here neither is made: a call from another kernel is the
    same native call as before, and a call from Python raises TypeError (it would otherwise jump
    to a null entry point)."""
    options.update(no_cpython_wrapper=True, no_cfunc_wrapper=True)
    cache = options.pop("cache", False)

    def decorate(fn):
        dispatcher = njit(**options)(fn)
        dispatcher.__class__ = InnerDispatcher
        _INNER.add(fn)
        if cache:
            dispatcher.enable_caching()  # (as an InnerDispatcher: its own cache files)
        return dispatcher

    return decorate(args[0]) if args else decorate


_INNER = weakref.WeakSet()  # the Python functions of the inner kernels
_LINKING = "gridrt-linking"  # the cache's name for an inner kernel's library: LLVM bitcode only


class _InnerLibrary(JITCodeLibrary):
    """The code library of an :func:`inner` kernel, compiled to LLVM IR and never to machine code.

    A kernel that calls an inner kernel links the inner one's IR into its own module, optimises
    it there and compiles that to machine code (numba's way for every jitted callee); the callee's own
    machine code is only ever reached through its Python entry point, which an inner kernel does
    not have.  numba still makes it, for each library it finalises: about 5 % of a cold
    one-frame dump (63 inner kernels; BENCHMARKS.md section 10).  This library finalises as
    numba's does (its callees linked in, the module checked) short of optimising the module, which
    each caller does with the caller's code, and of adding it to the JIT engine; the cache keeps
    its IR for linking (numba keeps that too, beside the machine code)."""

    def _optimize_final_module(self):
        """Nothing: the module is optimised in each caller's library, with the caller's code (numba
        optimises every library it finalises, so an inner kernel's code was optimised once for
        itself and again within each caller).  A cold start compiles less so, and the callers'
        code came out faster in the measurement of BENCHMARKS.md section 10: LLVM's inliner and
        vectorizers meet the inner kernels' code once, in each caller."""

    def _finalize_final_module(self):
        self._finalize_dynamic_globals()
        self._verify_declare_only_symbols()
        self._finalized = True

    def get_pointer_to_function(self, name):
        self._ensure_finalized()
        return 0  # (no machine code; an inner kernel has no entry point to find)

    def serialize_using_object_code(self):
        return (self.name, _LINKING, self._get_module_for_linking().as_bitcode())

    @classmethod
    def from_linking_bitcode(cls, codegen, name, bitcode):
        self = cls(codegen, name)
        self._final_module = self._shared_module = ll.parse_bitcode(bitcode)
        self._finalize_final_module()
        return self


class _InnerCacheImpl(caching.CompileResultCacheImpl):
    def get_filename_base(self, fullname, abiflags):
        return "inner-" + super().get_filename_base(fullname, abiflags)


class _InnerCache(caching.FunctionCache):
    """An inner kernel's on-disk cache: numba's, in files of their own (``inner-<module>.<name>-
    <line>.pyXY.nbi`` and ``.nbc``), since their entries are IR that only this module loads: a
    numba or gridrt without it finds no entry there, and compiles the kernel as it did."""

    _impl_class = _InnerCacheImpl


def _install_inner_libraries():
    """Give the inner kernels :class:`_InnerLibrary` code libraries: numba's lowering pass makes
    one for a gridrt inner kernel, a cache entry of one loads back as one, and numba's setting of
    a kernel's environment skips an environment that is in no machine code (an inner kernel's
    own one, when numba makes its never-called function object; its copy in each kernel that
    links it in is set as before).  Other kernels compile and
    load as numba makes them.  Where numba lacks a method this relies on (its code is not as this
    was written against), inner kernels compile as numba makes them."""
    if getattr(typed_passes.BaseNativeLowering.run_pass, "gridrt_inner", False):
        return
    needed = ((JITCodeLibrary, ("_finalize_final_module", "_finalize_dynamic_globals", "_verify_declare_only_symbols",
                                "_get_module_for_linking", "_ensure_finalized", "serialize_using_object_code",
                                "_unserialize")),
              (JITCPUCodegen, ("set_env",)),
              (typed_passes.BaseNativeLowering, ("run_pass",)))
    if not all(hasattr(cls, name) for cls, names in needed for name in names):
        return
    numba_run_pass = typed_passes.BaseNativeLowering.run_pass
    numba_unserialize = JITCodeLibrary._unserialize.__func__
    numba_set_env = JITCPUCodegen.set_env

    def run_pass(self, state):
        if state.library is None and state.func_id.func in _INNER:
            state.library = _InnerLibrary(state.targetctx.codegen(), state.func_id.func_qualname)
            state.library.enable_object_caching()
        return numba_run_pass(self, state)

    def _unserialize(cls, codegen, state):
        name, kind, data = state
        if kind == _LINKING:
            return _InnerLibrary.from_linking_bitcode(codegen, name, data)
        return numba_unserialize(cls, codegen, state)

    def set_env(self, env_name, env):
        if self._engine.get_global_value_address(env_name) == 0:
            return
        numba_set_env(self, env_name, env)

    run_pass.gridrt_inner = True
    run_pass.numba_run_pass = numba_run_pass  # (numba's pass, for a comparison to put back)
    typed_passes.BaseNativeLowering.run_pass = run_pass
    JITCodeLibrary._unserialize = classmethod(_unserialize)
    JITCPUCodegen.set_env = set_env


_install_inner_libraries()


def _load_ready(target_context):
    """Make the process ready to load a cached gridrt kernel, short of numba's full refresh.

    numba refreshes its target and typing contexts before every cache load: it imports and
    installs the typing and lowering registries of all its extensions (numpy, random, linalg,
    typed containers, ...), about a quarter of a warm one-frame dump, for kernels already in
    machine code.  A loaded kernel needs the symbols its code links against: numba's C helpers
    and math functions (registered when its context is made), the parallel runtime (each
    parallel kernel's own reload hook), the reference-counting runtime (initialised here), and
    the hash secret a hashing kernel reads (registered when numba.cpython.hashing is imported).
    A compile later in the same process runs the full refresh itself first."""
    rtsys.initialize(target_context)
    import numba.cpython.hashing  # noqa: F401  # deferred: its import registers the hash secret


def _is_gridrt(py_func):
    return getattr(py_func, "__module__", "").split(".")[0] == "gridrt"


def _install_quick_load():
    """Route cache loads of gridrt's own kernels through :func:`_load_ready`; every other
    function (a user's, a test's) loads as numba does it."""
    numba_load = caching.Cache.load_overload
    if getattr(numba_load, "gridrt_quick_load", False):
        return

    def load_overload(self, sig, target_context):
        if not _is_gridrt(self._py_func):
            return numba_load(self, sig, target_context)
        _load_ready(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    load_overload.gridrt_quick_load = True
    caching.Cache.load_overload = load_overload


_install_quick_load()


class _SharedScopeCopy:
    """The copy module as numba's inliner (numba.core.inline_closurecall) sees it: the blocks of
    one function's IR, deep-copied one after the other, share one memo.

    The inliner copies the IR of the function it inlines block by block, each with a fresh memo,
    and every block refers to the function's variable scope (all its variables): each block's
    copy copies the whole scope again, and keeps it only to read one scope's variables.  With one
    memo the scope and anything else the blocks share is copied once and stays shared, as in the
    IR copied.  A new memo starts with a block of another scope, or a block copied again (the next
    copy of the same IR, as the inliner makes a second one to return and overload inlining reuses
    one IR at several call sites)."""

    def __init__(self, block_type):
        self._block = block_type  # numba.core.ir.Block
        self._scope = None
        self._memo = {}

    def deepcopy(self, x, memo=None):
        if memo is not None or not isinstance(x, self._block):
            return copy.deepcopy(x, memo)
        if x.scope is not self._scope or id(x) in self._memo:
            self._scope, self._memo = x.scope, {}
        return copy.deepcopy(x, self._memo)

    def __getattr__(self, name):
        return getattr(copy, name)


_FRONTEND = []  # [True] once installed


def _install_cheaper_frontend():
    """The three changes the module docstring names, once per process at its first compile (the
    modules they change take about 0.1 s to import, which a warm start need not pay), each only
    where numba's code is as this was written against (else numba runs as it is).

    * :class:`_SharedScopeCopy` for the inliner's copy module: about 1.3 s of a cold one-frame
      dump's 27 s (BENCHMARKS.md section 10).
    * NumPy's array-operator typing template (npydecl.NumpyRulesArrayOperator) is one of the
      templates numba tries for every ``+``, ``*``, ``<``, ... it types; on scalars it resolves
      a ufunc loop and then returns None because no argument is an array.  Without an array
      argument it now returns None at once: its result when typing fails, as on scalars, and
      numba goes on to the scalar templates as before.  About 0.6 s of the same dump.
    * Compiler flags (numba.core.targetconfig.TargetConfig) compare equal when every option reads
      the same, explicit or default; numba builds both full dicts of option values for every
      comparison and hash, and its overload templates compare the current flags with their
      cache's keys at each call they type: about 58,000 comparisons (15 us each) and 20,000
      hashes in a cold one-frame dump of marbles, about 2 % of it (BENCHMARKS.md section 10).
      Flags of one class are compared on the options set in either, each against the other's
      setting or default; flags of two classes are compared as numba compares them.  The hash
      (numba's hashes the sorted option names alone) is numba's, made once a class."""
    if _FRONTEND:
        return
    _FRONTEND.append(True)
    from numba.core import inline_closurecall, ir  # deferred: numba's inliner, 0.1 s to import
    from numba.core.typing import npydecl  # deferred: numba's NumPy typing, imported by its compiler

    if inline_closurecall.copy is copy:
        inline_closurecall.copy = _SharedScopeCopy(ir.Block)
    rules = npydecl.NumpyRulesArrayOperator
    generic = rules.__dict__.get("generic")
    if generic is not None and not getattr(generic, "gridrt_arrays_only", False):
        def arrays_only(self, args, kws):
            if not any(isinstance(a, types.ArrayCompatible) for a in args):
                return None
            return generic(self, args, kws)

        arrays_only.gridrt_arrays_only = True
        arrays_only.numba_generic = generic
        rules.generic = arrays_only
    _install_quick_flag_compare(targetconfig.TargetConfig)


def _install_quick_flag_compare(config_cls):
    """The flags comparison of :func:`_install_cheaper_frontend` on ``config_cls`` (numba's
    TargetConfig), where its ``__eq__`` and ``__hash__`` are still numba's."""
    numba_eq, numba_hash = config_cls.__dict__.get("__eq__"), config_cls.__dict__.get("__hash__")
    if numba_eq is None or numba_hash is None or getattr(numba_eq, "gridrt_quick", False):
        return
    hashes, defaults = {}, {}

    def __eq__(self, other):
        cls = type(self)
        if cls is not type(other):
            return numba_eq(self, other)
        mine, theirs = self._values, other._values
        if mine == theirs:
            return True
        d = defaults.get(cls)
        if d is None:
            d = defaults[cls] = {k: option.default for k, option in cls.options.items()}
        # an option reads its explicit setting, else its default (numba's property getter); a
        # setting copied from flags of another class that is no option here is not compared
        return all(mine.get(k, d[k]) == theirs.get(k, d[k]) for k in mine.keys() | theirs.keys() if k in d)

    def __hash__(self):
        cls = type(self)
        h = hashes.get(cls)
        if h is None:
            h = hashes[cls] = numba_hash(self)
        return h

    __eq__.gridrt_quick = True
    __eq__.numba_eq, __hash__.numba_hash = numba_eq, numba_hash
    config_cls.__eq__, config_cls.__hash__ = __eq__, __hash__
