"""The D-3DGS deformation MLP (the baseline field), as the public reference code builds it."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from liquidgs.fields.base import DeformationField, Deltas, linear_flops, stacked_linear
from liquidgs.fields.config import FieldConfig
from liquidgs.fields.encoding import FieldInputs


class MLPField(DeformationField):
    """depth Linear layers of the given width with ReLU, input = [gamma(x); time features].

    Skip as in the reference: after layer index depth // 2 the activations are concatenated
    after the input features, [gamma(x); time; h], so layer depth // 2 + 1 is wider (run
    as products of its column blocks, see EncodedInputs). The
    reference only builds that wider layer when it exists (depth >= 3); shallower nets have
    no skip. Heads Linear(width, 3 / 4 / 3), no output activation, default nn.Linear init.
    dnerf preset: 522,280 parameters; nerfds preset: 506,378.
    """

    def __init__(self, config: FieldConfig):
        super().__init__(config)
        cfg = self.config
        self.encode = FieldInputs(cfg.xyz_freqs, cfg.time_freqs, cfg.timenet_width, cfg.timenet_out)
        in_dims = self.encode.out_dims
        width, depth = cfg.mlp_width, cfg.mlp_depth
        self.skip_after = depth // 2 if depth // 2 < depth - 1 else None
        self.layers = nn.ModuleList([nn.Linear(in_dims, width)])
        for i in range(depth - 1):
            self.layers.append(nn.Linear(width + in_dims if i == self.skip_after else width, width))
        self.head_xyz = nn.Linear(width, 3)
        self.head_rotation = nn.Linear(width, 4)
        self.head_scaling = nn.Linear(width, 3)

    def deltas(self, xyz: torch.Tensor, t: torch.Tensor) -> Deltas:
        inputs = self.encode(xyz, t)
        h = F.relu(inputs.linear(self.layers[0]))
        for i, layer in enumerate(self.layers[1:], start=1):
            h = F.relu(inputs.linear(layer, h) if i - 1 == self.skip_after else layer(h))
        return stacked_linear(h, [self.head_xyz, self.head_rotation, self.head_scaling])

    def flops_per_gaussian(self) -> int:
        return linear_flops(self)
