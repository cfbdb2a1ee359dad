"""Mission trees built from sm_bt behaviours (installed as ``sm_bt.trees``): XML mission files
(:mod:`sm_bt.trees.mission_xml`) and the bundled example, the MROS pilot (:mod:`sm_bt.trees.pilot`:
its trees, world, designs, the demo and the demo's ROS platform)."""
