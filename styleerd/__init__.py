"""styleerd: online motion style transfer (Style-ERD), frame by frame, on a CPU.

    import styleerd
    model = styleerd.load()                   # the shipped model
    live = model.stylizer("elderly", skeleton="me.bvh")
    out = live.step(frame)                    # one frame's BVH channel values in and out
    styleerd.transfer("walk.bvh", "exhausted", output="walk-exhausted.bvh")

The API (``styleerd.api``) is imported on first use, so ``import styleerd.motion.bvh`` and the
command line stay quick.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("styleerd")
except PackageNotFoundError:  # a checkout on sys.path without an install
    __version__ = "0+unknown"

__all__ = ["Model", "Stylizer", "__version__", "load", "read_motion", "transfer"]


def __getattr__(name: str):
    if name in __all__:
        from styleerd import api

        return getattr(api, name)
    raise AttributeError(f"module 'styleerd' has no attribute {name!r}")
