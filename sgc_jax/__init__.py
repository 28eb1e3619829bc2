"""sgc_jax: Spatial Geometric Consistency scores for videos, from estimator outputs (docs/semantics.md).

The public API, as explicit re-exports.
"""

from .adapters import import_clip
from .api import ENGINES, iter_scores, score_batch, score_clip
from .calibration import (COMPONENTS, Calibration, CalibrationMismatchError, KFoldStability, calibrate,
                          default_calibration, kfold_stability, sgc_score)
from .config import SGCConfig
from .engines.compile_cache import enable_compilation_cache
from .io.clip import Clip, ClipFormatError, save_batch, save_clip
from .io.loading import clip_from_arrays, load_clip, load_clips
from .io.result import CLIP_COLUMNS, PAIR_COLUMNS, BatchResult, ClipResult, PairArrays, read_scores, rescore_records
from .io.validate import ClipValidationError, ClipWarning, check_clip
from .research.perturb import MASK_CORRUPTIONS, PERTURBATIONS, perturb_clip
from .research.study import StudyResult, sensitivity_study
from .version import __version__


__all__ = [
    "__version__",
    "BatchResult", "CLIP_COLUMNS", "COMPONENTS", "Calibration", "CalibrationMismatchError", "Clip", "ClipFormatError", "ClipResult",
    "ClipValidationError", "ClipWarning", "ENGINES", "KFoldStability", "MASK_CORRUPTIONS", "PAIR_COLUMNS",
    "PERTURBATIONS", "PairArrays", "SGCConfig", "StudyResult",
    "calibrate", "check_clip", "clip_from_arrays", "default_calibration", "enable_compilation_cache", "import_clip", "iter_scores", "kfold_stability",
    "load_clip", "load_clips",
    "perturb_clip", "read_scores", "rescore_records", "save_batch", "save_clip", "score_batch", "score_clip",
    "sensitivity_study", "sgc_score",
]
