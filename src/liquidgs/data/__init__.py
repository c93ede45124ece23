"""Dynamic-scene datasets: D-NeRF and Nerfies-family readers, validation, synthetic scenes."""

from liquidgs.data.loading import CheckReport, check_dataset, detect_format, load_dataset
from liquidgs.data.perturb import PerturbConfig, perturb_dataset
from liquidgs.data.scene import DataConfig, Frame, SceneDataset, spread_extent
from liquidgs.data.synthetic import DEFAULT_SYNTHETIC_SCENE, SYNTHETIC_SCENES, generate_synthetic

__all__ = [
    "DEFAULT_SYNTHETIC_SCENE",
    "SYNTHETIC_SCENES",
    "CheckReport",
    "DataConfig",
    "Frame",
    "PerturbConfig",
    "SceneDataset",
    "check_dataset",
    "detect_format",
    "generate_synthetic",
    "load_dataset",
    "perturb_dataset",
    "spread_extent",
]
