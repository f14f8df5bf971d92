"""Half-inverse gradients: the rule (:mod:`.rule`) and the routes that compute its step
(:mod:`.routes`: full Jacobian, per layer (:mod:`.layers`), structured (:mod:`.structured`),
randomized (:mod:`.randomized`), Kronecker (:mod:`.kron`) and kept rows (:mod:`.fixed`)).
``HIG`` is imported on first use: the routes import their siblings through this package."""

import importlib

__all__ = ["HIG"]


def __getattr__(name: str):
    if name != "HIG":
        raise AttributeError(f"module 'pdeinv.methods.hig' has no attribute {name!r}")
    value = importlib.import_module(".rule", __name__).HIG
    globals()[name] = value
    return value
