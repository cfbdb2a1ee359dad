"""Model files shipped with sm_bt (installed as ``sm_bt.models``; see :mod:`sm_bt.bundled`)."""

from sm_bt.bundled import names, path

__all__ = ["names", "path"]
