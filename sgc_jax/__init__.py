"""sgc_jax: Spatial Geometric Consistency scores for videos, from estimator outputs (docs/semantics.md).

The public API, as explicit re-exports.
"""

from .adapters import import_clip
from .calibration import (
                          COMPONENTS,
                          Calibration,
                          CalibrationMismatchError,
                          KFoldStability,
                          calibrate,
                          default_calibration,
                          kfold_stability,
                          sgc_score,
)
from .config import SGCConfig
from .engines.evidence import EvidenceLevels
from .engines.jax_engine.compile_cache import enable_compilation_cache
from .engines.jax_engine.device_prepare import depth_without_ramps
from .engines.pairs import PairArrays
from .io.arrays import clip_from_arrays
from .io.clip import Clip, ClipFormatError, save_batch, save_clip
from .io.depth_range import depth_from_range
from .io.loading import load_clip, load_clips
from .io.tables import CLIP_COLUMNS, PAIR_COLUMNS, read_scores
from .io.validate import ClipValidationError, ClipWarning, check_clip
from .research.perturb import MASK_CORRUPTIONS, PERTURBATIONS, perturb_clip
from .research.study import StudyResult, sensitivity_study
from .scoring.api import iter_scores, score_batch, score_clip
from .scoring.engine_steps import ENGINES
from .scoring.options import RunOptions
from .scoring.result import BatchResult, ClipResult, camera_dynamics, rescore_records
from .scoring.reward import RewardOptions
from .scoring.scorer import Scorer, batch_of
from .scoring.streaming import StreamStats
from .version import __version__

__all__ = [
    "__version__",
    "BatchResult", "CLIP_COLUMNS", "COMPONENTS", "Calibration", "CalibrationMismatchError", "Clip", "ClipFormatError",
    "ClipResult", "ClipValidationError", "ClipWarning", "ENGINES", "EvidenceLevels", "KFoldStability", "MASK_CORRUPTIONS", "PAIR_COLUMNS",
    "PERTURBATIONS", "PairArrays", "RewardOptions", "RunOptions", "SGCConfig", "Scorer", "StreamStats", "StudyResult",
    "batch_of", "calibrate", "camera_dynamics", "check_clip", "clip_from_arrays", "default_calibration", "depth_from_range",
    "depth_without_ramps",
    "enable_compilation_cache", "import_clip", "iter_scores", "kfold_stability", "load_clip", "load_clips",
    "perturb_clip", "read_scores", "rescore_records", "save_batch", "save_clip", "score_batch", "score_clip",
    "sensitivity_study", "sgc_score",
]
