"""``python -m gridrt``: the command line of :mod:`gridrt.app` (view | dump | bench | strategies).

The one place in the engine's folder that names the app: it is the entry point, not part of the
engine, and nothing in the engine imports it.
"""

from gridrt.app.__main__ import main

raise SystemExit(main())
