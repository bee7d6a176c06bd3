"""Camera extrinsics of the cell measured from images (a printed board; the scene itself)."""
