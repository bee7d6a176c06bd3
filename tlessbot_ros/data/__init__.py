"""Files derived from the T-LESS CAD models (CC BY 4.0, Hodaň et al. 2017) shipped with the
package: a trained classifier, a template database, models_info.json. See README "Credits"."""
from pathlib import Path

DATA_DIR = Path(__file__).resolve().parent
DEFAULT_CLASSIFIER = DATA_DIR / 'classifier.npz'
DEFAULT_TEMPLATES = DATA_DIR / 'templates.npz'
DEFAULT_MODELS_INFO = DATA_DIR / 'models_info.json'
