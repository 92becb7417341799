"""The three steps of numba's compiler gridrt.compiles makes cheaper give what numba's own code gives.

They are installed at the first compile in the process (importing numba's inliner takes a tenth
of a second, which a warm start need not pay): a fresh process shows both before and after.

* Operator typing: NumPy's array-operator template, as installed, against numba's own template
  function on every operator it types, for scalar, array and mixed argument types.
* Compiler flags: equality and hash, as installed, against numba's own on flags with every
  option left at its default, set to it, or set to another value, in many combinations.
* The inliner's IR copies: blocks copied as numba's inliner copies them share one copied scope,
  share nothing with the IR copied or with the next copy of it; and kernels that inline
  functions (``inline="always"``, several call sites, nested, and an overload inlined at two call
  sites from one IR) compute what plain Python computes.
"""

import copy
import math

import numpy as np
import pytest
from numba import njit, types
from numba.core import ir
from numba.core.compiler import run_frontend
from numba.core.cpu import InlineOptions
from numba.core.registry import cpu_target
from numba.core.typing import npydecl
from numba.extending import overload

import gridrt.compiles as compiles  # noqa: F401  (installs the cheaper steps)

@pytest.fixture
def compiled():
    """numba has compiled in this process (the cheaper steps are installed then)."""
    @njit
    def plus_one(x):
        return x + 1

    assert plus_one(1) == 2


def test_installed_at_the_first_compile_not_at_import():
    import subprocess
    import sys

    code = ("import sys, copy, gridrt\n"
            "print('numba.core.inline_closurecall' in sys.modules)\n"
            "from numba import njit\n"
            "njit(lambda x: x + 1)(1)\n"
            "from numba.core import inline_closurecall\n"
            "from numba.core.typing import npydecl\n"
            "from numba.core.targetconfig import TargetConfig\n"
            "print(inline_closurecall.copy is not copy, npydecl.NumpyRulesArrayOperator.generic.gridrt_arrays_only,\n"
            "      TargetConfig.__eq__.gridrt_quick)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["False", "True", "True", "True"]


def _other_value(option):
    """A valid setting of ``option`` other than its default (None where none is known)."""
    d = option.default
    if isinstance(d, bool):
        return not d
    if isinstance(d, int):
        return d + 1
    if isinstance(d, str):
        return {"python": "numpy", "numpy": "python"}.get(d)
    if option.type is InlineOptions:
        return "always"
    return {"ParallelOptions": True, "FastMathOptions": {"nnan", "ninf"}}.get(option.type.__name__)


def test_flag_comparison_is_numbas_own(compiled):
    import random

    from numba.core.compiler import Flags
    from numba.core.targetconfig import TargetConfig

    eq, hsh = TargetConfig.__eq__, TargetConfig.__hash__
    assert getattr(eq, "gridrt_quick", False), "the flags comparison is not installed"
    numba_eq, numba_hash = eq.numba_eq, hsh.numba_hash
    settings = {}
    for name, option in Flags.options.items():
        other = _other_value(option)
        default = {"InlineOptions": "never", "ParallelOptions": False, "FastMathOptions": set()}.get(
            option.type.__name__, option.default)  # (the setting that reads as the default)
        settings[name] = [default] + ([other] if other is not None else [])
    assert sum(len(v) > 1 for v in settings.values()) >= 10

    rng = random.Random(7)
    made = []
    for _ in range(300):
        f = Flags()
        for name in rng.sample(sorted(settings), rng.randint(0, 4)):
            setattr(f, name, rng.choice(settings[name]))  # the default set explicitly, or another value
        made.append(f)
    made.append(Flags(made[5]))  # a copy
    pairs = [(a, b) for a in made[:60] for b in made] + [(a, a) for a in made]
    equal = 0
    for a, b in pairs:
        want = numba_eq(a, b)
        assert (a == b) is want, (a, b)
        equal += want
        assert hash(a) == numba_hash(a)
    assert equal > len(made) + 60  # equal pairs with different explicit settings among them
    assert (made[0] == object()) is False


SCALARS = [types.int64, types.int32, types.uint8, types.float64, types.float32, types.boolean, types.complex128]
ARRAYS = [types.Array(types.float64, 1, "C"), types.Array(types.int32, 2, "C"), types.Array(types.float32, 3, "A")]


def _op_templates():
    subs = [c for c in npydecl.NumpyRulesArrayOperator.__subclasses__() if "generic" not in c.__dict__]
    assert len(subs) >= 10  # one per operator numba types through NumPy's rules
    return subs


def test_operator_typing_is_numbas_own(compiled):
    generic = npydecl.NumpyRulesArrayOperator.generic
    assert getattr(generic, "gridrt_arrays_only", False), "the array-only template is not installed"
    numba_generic = generic.numba_generic
    ctx = cpu_target.typing_context
    ctx.refresh()
    checked = arrays = 0
    for cls in _op_templates():
        tmpl = cls(ctx)
        for a in SCALARS + ARRAYS:
            for b in SCALARS + ARRAYS:
                for args in ((a, b), (a,)):
                    try:
                        want = numba_generic(tmpl, args, {})
                    except Exception as e:  # noqa: BLE001 (then the installed one raises alike)
                        with pytest.raises(type(e)):
                            tmpl.generic(args, {})
                        continue
                    got = tmpl.generic(args, {})
                    assert got == want, (cls.key, args, got, want)
                    checked += 1
                    arrays += want is not None
    assert checked > 1000 and arrays > 100  # (array arguments do resolve through it)


def _blocks_copied(func_ir):
    """The IR's blocks copied as numba's inliner copies them (one deepcopy call a block)."""
    from numba.core import inline_closurecall

    return {label: inline_closurecall.copy.deepcopy(block) for label, block in func_ir.blocks.items()}


def _objects(blocks):
    seen = {}

    def walk(x, depth=0):
        if id(x) in seen or depth > 50:
            return
        if isinstance(x, (ir.Block, ir.Var, ir.Assign, ir.Expr, ir.Scope, ir.Loc, ir.Const, ir.Global)):
            seen[id(x)] = x
            for v in vars(x).values():
                walk(v, depth + 1)
        elif isinstance(x, (list, tuple)):
            for v in x:
                walk(v, depth + 1)
        elif isinstance(x, dict):
            for v in x.values():
                walk(v, depth + 1)

    for b in blocks.values():
        walk(b)
    return seen


def _several_blocks(x, n):
    s = 0.0
    for i in range(n):
        if i % 3 == 0:
            s += x * i
        elif i % 3 == 1:
            s -= math.sqrt(abs(x) + i)
        else:
            s *= 0.5
    return s


def test_inliner_copies_share_one_scope_and_nothing_else(compiled):
    from numba.core import inline_closurecall

    assert isinstance(inline_closurecall.copy, compiles._SharedScopeCopy)
    func_ir = run_frontend(_several_blocks)
    assert len(func_ir.blocks) > 4
    first = _blocks_copied(func_ir)
    second = _blocks_copied(func_ir)
    scopes = {id(b.scope) for b in first.values()}
    assert len(scopes) == 1 and id(func_ir.blocks[min(func_ir.blocks)].scope) not in scopes
    assert {id(b.scope) for b in second.values()} != scopes
    orig, a, b = _objects(func_ir.blocks), _objects(first), _objects(second)
    # what they share with the IR and with each other: only the source locations, which numba's
    # own copy (one deepcopy a block) shares too
    own = _objects({label: copy.deepcopy(block) for label, block in func_ir.blocks.items()})
    assert {type(orig[i]) for i in set(own) & set(orig)} == {ir.Loc}
    for x, y in ((a, orig), (b, orig), (a, b)):
        assert {type(x[i]) for i in set(x) & set(y)} == {ir.Loc}
    # the copies hold the same code
    for label, block in func_ir.blocks.items():
        assert [str(s) for s in first[label].body] == [str(s) for s in block.body] == [str(s) for s in second[label].body]


@njit(inline="always")
def _step(x, k):
    if x > k:
        return x - k
    return x * 2.0 + k


@njit(inline="always")
def _two_steps(x, k):
    return _step(_step(x, k), k + 1.0)


def _clamp_py(x):
    return min(max(x, -1.0), 1.0)


def _clamp(x):
    raise NotImplementedError


@overload(_clamp, inline="always")
def _ol_clamp(x):
    def impl(x):
        if x < -1.0:
            return -1.0
        if x > 1.0:
            return 1.0
        return x
    return impl


@njit
def _inlining_kernel(a, out):
    for i in range(a.shape[0]):
        x = a[i]
        y = _step(x, 1.0) + _two_steps(x, 0.5)
        out[i] = _clamp(y) + _clamp(x) + _step(y, 2.0)


def test_kernels_that_inline_compute_what_python_computes():
    a = np.linspace(-3.0, 3.0, 101)
    out = np.empty_like(a)
    _inlining_kernel(a, out)
    step, two = _step.py_func, _two_steps.py_func
    two_py = lambda x, k: step(step(x, k), k + 1.0)  # noqa: E731
    assert two(0.3, 0.5) == two_py(0.3, 0.5)
    want = [_clamp_py(step(x, 1.0) + two_py(x, 0.5)) + _clamp_py(x) + step(step(x, 1.0) + two_py(x, 0.5), 2.0)
            for x in a]
    np.testing.assert_array_equal(out, want)
