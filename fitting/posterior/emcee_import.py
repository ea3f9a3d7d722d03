"""emcee, imported on first use without SciPy's statistics module.

emcee 3 imports ``scipy.stats`` at import time for one thing only: ``gaussian_kde`` in
its ``KDEMove`` (``emcee/moves/kde.py``: ``try: from scipy.stats import gaussian_kde
except ImportError: gaussian_kde = None``). The toolkit's samplers never use that move,
and ``scipy.stats`` costs about 0.4 s of import on the 2-core machine: most of what the
posterior check's ``import emcee`` took in a warm ``cstiffjax diagnose`` (benchmarks/LATENCY.md).
:func:`emcee` therefore imports emcee while a finder refuses ``scipy.stats``
to the importing thread only (other threads import it as usual), then gives
``KDEMove`` a stand-in for ``gaussian_kde`` that imports the real one when a KDE move
first runs: emcee behaves exactly as before for every move, ``KDEMove`` included.
"""

import importlib.abc
import sys
import threading

_LOCK = threading.Lock()


class _DeferStats(importlib.abc.MetaPathFinder):
    """Refuses ``scipy.stats`` (an ``ImportError``, which emcee catches) to one thread."""

    def __init__(self) -> None:
        self.thread = threading.get_ident()

    def find_spec(self, fullname, path=None, target=None):
        if fullname == "scipy.stats" and threading.get_ident() == self.thread:
            raise ImportError("scipy.stats is imported when emcee's KDEMove first runs "
                              "(fitting.posterior.emcee_import)")
        return None


def _gaussian_kde(*args, **kwargs):
    """``scipy.stats.gaussian_kde``, imported on first call (the stand-in of :func:`emcee`)."""
    from scipy.stats import gaussian_kde

    return gaussian_kde(*args, **kwargs)


def emcee():
    """The ``emcee`` module, imported on first call without ``scipy.stats`` (module doc).

    **Returns:** the module (the same object as ``import emcee``)."""
    if "emcee" in sys.modules:  # (an import statement: waits for an import under way elsewhere)
        import emcee as module

        return module
    with _LOCK:
        if "scipy.stats" in sys.modules:  # nothing to save: import as usual
            import emcee as module

            return module
        finder = _DeferStats()
        sys.meta_path.insert(0, finder)
        try:
            import emcee as module
        finally:
            sys.meta_path.remove(finder)
        kde = sys.modules.get("emcee.moves.kde")
        if kde is not None and getattr(kde, "gaussian_kde", None) is None:
            kde.gaussian_kde = _gaussian_kde
        return module
