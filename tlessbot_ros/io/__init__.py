"""Reading and writing files: CAD models, BOP datasets, model and template archives."""
