"""Camera calibration of the cell: the rig estimated from the scene the cameras see
(:mod:`.scene`), with the in-plane geometry it needs (:mod:`.inplane`), and what a running
localiser does with it (:mod:`.refinement`); or measured once with a printed ChArUco board
(:mod:`.board`)."""
