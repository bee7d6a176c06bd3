"""Scene simulator: two-view RGB-D table scenes of CAD models with ground truth."""
