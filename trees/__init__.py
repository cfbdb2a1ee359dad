"""Mission trees built from sm_bt behaviours (installed as ``sm_bt.trees``)."""
