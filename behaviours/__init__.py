"""Mode behaviours for py_trees (installed as ``sm_bt.behaviours``)."""
