"""What camera refinement and exposure compensation share: two learned tensors of three numbers per
training frame, zero at the start (the frame as given), in one Adam, and how a checkpoint keeps them."""

from __future__ import annotations

import abc
from pathlib import Path

import torch

from liquidgs.atomic import write_json_atomic
from liquidgs.errors import LiquidGSError


class FrameCorrections(abc.ABC):
    """Subclasses name their two tensors (KEYS, also their checkpoint keys), what the correction is
    called (WHAT), what it does to a frame (VERB) and the flag that turns it off (OFF_FLAG), and
    give report(iteration), the JSON the run folder keeps of them."""

    KEYS: tuple[str, str]
    WHAT: str
    VERB: str
    OFF_FLAG: str

    def __init__(self, frames: list, device):
        self.names = [frame.name for frame in frames]
        for key in self.KEYS:
            setattr(self, key, torch.nn.Parameter(torch.zeros(len(frames), 3, device=device)))
        self.optimizer: torch.optim.Optimizer | None = None
        """Set by the subclass, over the tensors of KEYS."""

    def state_dict(self) -> dict:
        return {
            "names": list(self.names),
            **{key: getattr(self, key).detach().cpu().clone() for key in self.KEYS},
            "optimizer": self.optimizer.state_dict(),
        }

    def load_state_dict(self, saved: dict | None, source: Path) -> None:
        if saved is None:
            raise LiquidGSError(f"{source}: the checkpoint was trained without {self.WHAT}; "
                                f"resume it with {self.OFF_FLAG}")  # fmt: skip
        if saved["names"] != self.names:
            raise LiquidGSError(f"{source}: the checkpoint {self.VERB} other training frames than the scene holds")
        with torch.no_grad():
            for key in self.KEYS:
                getattr(self, key).copy_(saved[key])
        self.optimizer.load_state_dict(saved["optimizer"])

    @abc.abstractmethod
    def report(self, iteration: int) -> dict:
        """The JSON the run folder keeps of the corrections at this iteration."""

    def write(self, path: Path, iteration: int) -> None:
        write_json_atomic(path, self.report(iteration))
