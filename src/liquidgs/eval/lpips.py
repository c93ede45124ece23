"""LPIPS v0.1 (Zhang et al. 2018) with our own network code, numerically matching the `lpips` package.

The pipeline: ScalingLayer -> backbone (torchvision's AlexNet / SqueezeNet 1.1 / VGG16
``features``, tapped after the same ReLUs as the lpips package) -> unit-normalise each tap
along channels -> squared difference -> learned 1x1 "lin" layer -> spatial mean -> sum
over taps.

Two kinds of weights are needed:

- backbone weights, torchvision ``features.*`` state dicts, looked for in this order: the
  explicit ``weights`` argument (CLI ``--lpips-weights``); the ``LIQUIDGS_LPIPS_WEIGHTS``
  environment variable; the torch hub cache (``$TORCH_HOME/hub/checkpoints``, by default
  ``~/.cache/torch/hub/checkpoints``) under torchvision's own file names. The argument and
  the variable may name a file or a directory holding ``<model>_features.pth`` (e.g.
  ``alexnet_features.pth``) or torchvision's file name.
- the lin-layer weights, which ship inside the PyPI ``lpips`` package
  (``lpips/weights/v0.1/<backbone>.pth``); the package is located, never imported (it
  needs torchvision).

Missing or unreadable weights raise :class:`LPIPSUnavailable`, whose message says which
files were looked for, so callers can report the metric as unavailable with that reason.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.eval.metrics import image_pair

WEIGHTS_ENV = "LIQUIDGS_LPIPS_WEIGHTS"
LPIPS_VERSION = "0.1"

# lpips' ScalingLayer: maps [-1, 1] inputs to roughly ImageNet-normalised ones.
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
_UNIT_EPS = 1e-10


class LPIPSUnavailable(LiquidGSError):
    """LPIPS cannot be computed (weights missing or unreadable); the message names the metric and says why."""

    def __init__(self, backbone: str, reason: str):
        super().__init__(f"{metric_name(backbone)} unavailable: {reason}")
        self.backbone = backbone


@dataclass(frozen=True)
class _Backbone:
    name: str  # how reports name the metric, e.g. LPIPS-VGG (the paper's)
    model: str  # torchvision's model name
    hub_file: str  # torchvision's checkpoint file name in the torch hub cache
    taps: tuple[int, ...]  # indices in ``features`` whose outputs LPIPS compares
    channels: tuple[int, ...]  # channels of those outputs, one lin layer each
    min_side: int  # smallest image side whose last tap still has a pixel (measured on the layouts)


BACKBONES = {
    "alex": _Backbone(
        "LPIPS-Alex", "alexnet", "alexnet-owt-7be5be79.pth", (1, 4, 7, 9, 11), (64, 192, 384, 256, 256), 31
    ),
    "squeeze": _Backbone(
        "LPIPS-Squeeze",
        "squeezenet1_1",
        "squeezenet1_1-b8a52dc0.pth",
        (1, 4, 7, 9, 10, 11, 12),
        (64, 128, 256, 384, 384, 512, 512),
        17,
    ),
    "vgg": _Backbone("LPIPS-VGG", "vgg16", "vgg16-397923af.pth", (3, 8, 15, 22, 29), (64, 128, 256, 512, 512), 16),
}


class _Fire(nn.Module):
    """SqueezeNet's Fire module, with torchvision's attribute names so its weights load."""

    def __init__(self, in_channels: int, squeeze: int, expand: int):
        super().__init__()
        self.squeeze = nn.Conv2d(in_channels, squeeze, kernel_size=1)
        self.expand1x1 = nn.Conv2d(squeeze, expand, kernel_size=1)
        self.expand3x3 = nn.Conv2d(squeeze, expand, kernel_size=3, padding=1)
        self.relu = nn.ReLU()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        s = self.relu(self.squeeze(x))
        return torch.cat([self.relu(self.expand1x1(s)), self.relu(self.expand3x3(s))], dim=1)


# Each layout reproduces torchvision's ``features`` indices up to the last LPIPS tap; the
# trailing max-pool that only feeds the classifier is left out.
def _alexnet_features() -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(384, 256, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(256, 256, kernel_size=3, padding=1),
        nn.ReLU(),
    )


def _squeezenet1_1_features() -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=3, stride=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2, ceil_mode=True),
        _Fire(64, 16, 64),
        _Fire(128, 16, 64),
        nn.MaxPool2d(kernel_size=3, stride=2, ceil_mode=True),
        _Fire(128, 32, 128),
        _Fire(256, 32, 128),
        nn.MaxPool2d(kernel_size=3, stride=2, ceil_mode=True),
        _Fire(256, 48, 192),
        _Fire(384, 48, 192),
        _Fire(384, 64, 256),
        _Fire(512, 64, 256),
    )


def _vgg16_features() -> nn.Sequential:
    layers: list[nn.Module] = []
    in_channels = 3
    # VGG16 configuration "D": channel counts, "M" = 2x2 max-pool; the final pool is dropped.
    for item in (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512):
        if item == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(in_channels, item, kernel_size=3, padding=1), nn.ReLU()]
            in_channels = item
    return nn.Sequential(*layers)


_FEATURE_BUILDERS = {"alex": _alexnet_features, "squeeze": _squeezenet1_1_features, "vgg": _vgg16_features}


def _check_backbone(backbone: str) -> _Backbone:
    if backbone not in BACKBONES:
        raise ConfigError(f"unknown LPIPS backbone '{backbone}' (choose from {', '.join(BACKBONES)})")
    return BACKBONES[backbone]


def metric_name(backbone: str) -> str:
    """The metric's name in reports (LPIPS-VGG, LPIPS-Alex, LPIPS-Squeeze)."""
    return _check_backbone(backbone).name


def _candidates(location: Path, spec: _Backbone) -> list[Path]:
    """The files a user-given location stands for: itself, or the known names inside a directory."""
    if location.is_dir():
        return [location / f"{spec.model}_features.pth", location / spec.hub_file]
    return [location]


def resolve_backbone_weights(backbone: str, weights: str | Path | None = None) -> tuple[Path, str]:
    """Find the backbone weight file; return it and where it came from.

    An explicit ``weights`` path is used alone (a user's choice is never silently replaced by
    another file); otherwise the environment variable, then the torch hub cache, are tried.
    """
    spec = _check_backbone(backbone)
    searched: list[tuple[str, Path]] = []
    if weights is not None:
        searched += [("weights argument", c) for c in _candidates(Path(weights).expanduser(), spec)]
    else:
        env_value = os.environ.get(WEIGHTS_ENV)
        if env_value:
            location = Path(env_value).expanduser()
            if not location.exists():
                raise LPIPSUnavailable(backbone, f"backbone weights: ${WEIGHTS_ENV}={location} does not exist")
            searched += [(f"${WEIGHTS_ENV}", c) for c in _candidates(location, spec)]
        searched.append(("torch hub cache", Path(torch.hub.get_dir()) / "checkpoints" / spec.hub_file))
    for source, path in searched:
        if path.is_file():
            return path, source
    raise LPIPSUnavailable(
        backbone,
        f"backbone weights not found; looked for: {', '.join(str(p) for _, p in searched)} "
        f"(pass --lpips-weights or set ${WEIGHTS_ENV} to a file or folder with {spec.model}_features.pth)",
    )


def lin_weights_path(backbone: str) -> Path:
    """The lpips package's v0.1 lin-layer weight file for ``backbone``, found without importing lpips."""
    _check_backbone(backbone)
    found = importlib.util.find_spec("lpips")
    if found is None or not found.submodule_search_locations:
        raise LPIPSUnavailable(
            backbone,
            f"lin-layer weights: the PyPI package 'lpips' is not installed "
            f"(its file lpips/weights/v{LPIPS_VERSION}/{backbone}.pth is needed)",
        )
    package_dir = Path(next(iter(found.submodule_search_locations)))
    path = package_dir / "weights" / f"v{LPIPS_VERSION}" / f"{backbone}.pth"
    if not path.is_file():
        raise LPIPSUnavailable(backbone, f"lin-layer weights: {path} does not exist")
    return path


def _load_state_dict(path: Path, backbone: str, what: str) -> dict[str, torch.Tensor]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any failure to read the file means the same thing to the user
        raise LPIPSUnavailable(backbone, f"{what}: cannot read {path}: {type(exc).__name__}: {exc}") from exc
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise LPIPSUnavailable(backbone, f"{what}: {path} is not a state dict of tensors")
    return state


class LPIPS(nn.Module):
    """LPIPS v0.1 distance between images in [0, 1], one score per image.

    ``normalize=True`` maps [0, 1] inputs to the [-1, 1] range LPIPS expects (correct use).
    ``normalize=False`` feeds [0, 1] images unchanged where [-1, 1] is expected, the D-3DGS
    reference's quirk, to reproduce its published numbers.

    Call as ``lpips(img, ref)`` on [H, W, 3] (0-d result) or [B, H, W, 3] ([B] result).
    Weights are frozen; gradients still flow to the inputs.
    """

    def __init__(
        self,
        backbone: str = "alex",
        normalize: bool = True,
        weights: str | Path | None = None,
        device: str | torch.device = "cpu",
    ):
        super().__init__()
        spec = _check_backbone(backbone)
        self.backbone = backbone
        self.normalize = normalize
        self.taps = spec.taps
        self.min_side = spec.min_side
        self.weights_path, self.weights_source = resolve_backbone_weights(backbone, weights)
        self.lin_path = lin_weights_path(backbone)

        # The layers are built with random weights that the files then replace: drawn from a forked
        # generator, so that whether LPIPS is available never moves a training run's random numbers.
        with torch.random.fork_rng(devices=[]):
            self.features = _FEATURE_BUILDERS[backbone]()
            self.lins = nn.ModuleList(nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in spec.channels)
        what = "backbone weights"
        state = _load_state_dict(self.weights_path, backbone, what)
        # Full torchvision checkpoints also hold the classifier; only ``features.*`` is used.
        prefix = "features."
        features_state = {k.removeprefix(prefix): v for k, v in state.items() if k.startswith(prefix)}
        self._load_into(self.features, features_state, self.weights_path, what)

        lin_state = _load_state_dict(self.lin_path, backbone, "lin-layer weights")
        # The lpips package names them lin<k>.model.1.weight (index 0 is a dropout).
        lin_state = {f"{k}.weight": lin_state.get(f"lin{k}.model.1.weight") for k in range(len(self.lins))}
        lin_state = {k: v for k, v in lin_state.items() if v is not None}
        self._load_into(self.lins, lin_state, self.lin_path, "lin-layer weights")

        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()
        self.to(device)

    def _load_into(self, module: nn.Module, state: dict[str, torch.Tensor], path: Path, what: str) -> None:
        """Load ``state`` strictly, or say in one line how the file differs from the network."""
        expected = module.state_dict()
        problems = []
        missing = sorted(expected.keys() - state.keys())
        if missing:
            problems.append(f"{len(missing)} tensors missing (first: {missing[0]})")
        unexpected = sorted(state.keys() - expected.keys())
        if unexpected:
            problems.append(f"{len(unexpected)} unexpected tensors (first: {unexpected[0]})")
        problems += [
            f"{key} has shape {tuple(state[key].shape)}, expected {tuple(expected[key].shape)}"
            for key in sorted(expected.keys() & state.keys())
            if state[key].shape != expected[key].shape
        ]
        if problems:
            raise LPIPSUnavailable(self.backbone, f"{what}: {path} does not fit the network: {'; '.join(problems[:3])}")
        module.load_state_dict(state)

    def _tapped_features(self, x: torch.Tensor) -> list[torch.Tensor]:
        outputs = []
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in self.taps:
                outputs.append(x)
        return outputs

    def forward(self, img: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        img_b, ref_b, single = image_pair(img, ref)
        height, width = img_b.shape[1:3]
        if min(height, width) < self.min_side:
            raise LPIPSUnavailable(
                self.backbone, f"images of {width}x{height} are smaller than the {self.min_side} px its network needs"
            )
        batch = img_b.shape[0]
        # Both images go through the backbone as one batch, channel-first.
        x = torch.cat([img_b, ref_b]).permute(0, 3, 1, 2).to(self.shift.device, self.shift.dtype)
        if self.normalize:
            x = 2 * x - 1
        x = (x - self.shift) / self.scale

        total = torch.zeros(batch, device=x.device, dtype=x.dtype)
        for feats, lin in zip(self._tapped_features(x), self.lins):
            unit = feats / (feats.pow(2).sum(dim=1, keepdim=True).sqrt() + _UNIT_EPS)
            diff = (unit[:batch] - unit[batch:]).pow(2)
            total = total + lin(diff).mean(dim=(1, 2, 3))
        return total[0] if single else total

    def describe(self) -> dict[str, object]:
        """What results.json records about this metric."""
        return {
            "backbone": self.backbone,
            "metric": metric_name(self.backbone),
            "version": LPIPS_VERSION,
            "normalize": self.normalize,
            "input_range": "[0,1] mapped to [-1,1]"
            if self.normalize
            else "[0,1] fed as [-1,1] (D-3DGS reference quirk)",
            "weights": str(self.weights_path),
            "weights_source": self.weights_source,
            "lin_weights": str(self.lin_path),
        }
