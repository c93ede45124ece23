"""Per-Gaussian keyframe tracks: each Gaussian has as many keyframes as its motion needs (one if
it does not move), at keyframe_times(its count), and follows motion.interpolate between them.

In memory the Gaussians are grouped by keyframe count (one [K, n, 10] tensor per count), so a
frame costs one weighted sum per count. On disk (pack / unpack) every channel is quantised
against its Gaussian's own range over its keyframes:

    counts        int16 [N]    keyframes per Gaussian
    wide          uint8 [N]    bit c set: channel group c (position, rotation, scale) uses 16 bits
    low           float32 [N, 10], span float16 [N, 10]: value = low + span * code / (2^bits - 1)
    codes8        uint8, codes16 int16 (code - 32768): the codes of Gaussians of more than one
                  keyframe, block by block in the order blocks() gives (count ascending, then
                  channel group, then 8 before 16 bits), each block [K, n, width] with its
                  Gaussians in ascending order

A Gaussian of one keyframe stores its value in `low` (span 0) and no codes. row_codes holds
other per-Gaussian values (a baked scene's higher SH coefficients) the same way, 8 bits of each
Gaussian's range.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from liquidgs.bake.motion import (
    CHANNELS,
    POSITION,
    QUATERNION,
    SCALE,
    interpolation_matrix,
    keyframe_times,
    spline_weights,
)

CHANNEL_GROUPS = (POSITION, QUATERNION, SCALE)
CODE_LEVELS = {8: 255, 16: 65535}
ALL_WIDE = (1 << len(CHANNEL_GROUPS)) - 1
"""`wide` with every channel group on 16 bits."""


@dataclass
class Tracks:
    counts: torch.Tensor
    """[N] keyframes per Gaussian."""
    groups: list[tuple[torch.Tensor, torch.Tensor]]
    """(Gaussian indices [n], keyframes [K, n, 10]) per distinct count K, count ascending."""

    @classmethod
    def from_keyframes(cls, keyframes: torch.Tensor) -> Tracks:
        """Every Gaussian on the same keyframes [K, N, 10]."""
        n = keyframes.shape[1]
        return cls(torch.full((n,), keyframes.shape[0], dtype=torch.long), [(torch.arange(n), keyframes)])

    @property
    def gaussians(self) -> int:
        return int(self.counts.shape[0])

    def __post_init__(self):
        still = [(index, keyframes[0]) for index, keyframes in self.groups if keyframes.shape[0] == 1]
        self._still = (torch.cat([i for i, _ in still]), torch.cat([k for _, k in still])) if still else None
        self._moving = [(index, keyframes) for index, keyframes in self.groups if keyframes.shape[0] > 1]

    def at_time(self, time: float) -> torch.Tensor:
        """The state [N, 10] at `time`, quaternions unit length: the Gaussians of one keyframe
        copied, each other count one weighted sum of its (up to) four keyframes around `time`
        (motion.spline_weights), the quaternions normalised once for all."""
        keys = self.groups[0][1]
        state = torch.empty(self.gaussians, CHANNELS, dtype=keys.dtype, device=keys.device)
        if self._still is not None:
            state[self._still[0]] = self._still[1]
        for index, keyframes in self._moving:
            first, weights = spline_weights(keyframes.shape[0], time)
            span = keyframes[first : first + len(weights)]
            state[index] = torch.tensordot(torch.tensor(weights, dtype=span.dtype, device=span.device), span, 1)
        state[:, QUATERNION] = torch.nn.functional.normalize(state[:, QUATERNION], dim=-1)
        return state

    def uniform(self) -> torch.Tensor:
        """[K, N, 10]: every track sampled at keyframe_times(K), K the most keyframes of any Gaussian
        (for a player that takes one keyframe count for all)."""
        return self.sampled(keyframe_times(int(self.counts.max())))

    def sampled(self, times: torch.Tensor) -> torch.Tensor:
        """The states [len(times), N, 10] at every time (one matrix product per count)."""
        keys = self.groups[0][1]
        states = torch.empty(len(times), self.gaussians, CHANNELS, dtype=keys.dtype, device=keys.device)
        for index, keyframes in self.groups:
            matrix = interpolation_matrix(keyframes.shape[0], times).to(keyframes)
            part = (matrix @ keyframes.reshape(keyframes.shape[0], -1)).reshape(len(times), *keyframes.shape[1:])
            part[..., QUATERNION] = torch.nn.functional.normalize(part[..., QUATERNION], dim=-1)
            states[:, index] = part
        return states


def blocks(counts: torch.Tensor, wide: torch.Tensor):
    """(count, channel group, bits, Gaussian indices) of every block of codes, in file order."""
    for count in sorted(set(counts.tolist()) - {1}):
        members = counts == count
        for group, channels in enumerate(CHANNEL_GROUPS):
            is_wide = (wide >> group) & 1 == 1
            for bits, chosen in ((8, ~is_wide), (16, is_wide)):
                index = (members & chosen).nonzero().flatten()
                if len(index):
                    yield count, channels, bits, index


def pack(tracks: Tracks, wide: torch.Tensor) -> dict[str, torch.Tensor]:
    """The tracks quantised (module docstring); `wide` [N] uint8: the channel groups that need 16 bits."""
    n = tracks.gaussians
    low = torch.empty(n, CHANNELS, dtype=torch.float32)
    high = torch.empty(n, CHANNELS, dtype=torch.float32)
    for index, keyframes in tracks.groups:
        low[index], high[index] = keyframes.float().cpu().amin(0), keyframes.float().cpu().amax(0)
    # float16 span rounded up, so that the highest value still has a code: (span) * (1 + 2^-10) >= span.
    span = ((high - low) * (1 + 2**-10)).to(torch.float16)
    codes = {8: [], 16: []}
    by_count = {keyframes.shape[0]: (index, keyframes.float().cpu()) for index, keyframes in tracks.groups}
    for count, channels, bits, index in blocks(tracks.counts, wide):
        group_index, keyframes = by_count[count]
        position = torch.searchsorted(group_index, index)
        values = keyframes[:, position, channels]
        scale = span[index, channels].float()
        fraction = (values - low[index, channels]) / torch.where(scale > 0, scale, torch.ones_like(scale))
        code = (fraction * CODE_LEVELS[bits]).round().clamp(0, CODE_LEVELS[bits])
        codes[bits].append(code.flatten())
    joined = {bits: torch.cat(parts) if parts else torch.zeros(0) for bits, parts in codes.items()}
    return {
        "counts": tracks.counts.to(torch.int16),
        "wide": wide.to(torch.uint8),
        "low": low,
        "span": span,
        "codes8": joined[8].to(torch.uint8),
        "codes16": (joined[16] - 32768).to(torch.int16),
    }


def unpack(payload: dict[str, torch.Tensor], n: int) -> Tracks:
    """The tracks of pack()'s payload for `n` Gaussians; ValueError naming what does not fit."""
    counts, wide = payload["counts"].long(), payload["wide"].long()
    low, span = payload["low"].float(), payload["span"].float()
    if counts.shape != (n,) or wide.shape != (n,) or low.shape != (n, CHANNELS) or span.shape != (n, CHANNELS):
        raise ValueError(f"motion tables do not fit {n} Gaussians")
    if n and (int(counts.min()) < 1 or int(wide.max()) > ALL_WIDE):
        raise ValueError("keyframe counts below 1 or unknown code widths")
    streams = {8: payload["codes8"].float(), 16: payload["codes16"].float() + 32768}
    used = {8: 0, 16: 0}
    groups = {count: low[counts == count][None].repeat(count, 1, 1) for count in sorted(set(counts.tolist()))}
    for count, channels, bits, index in blocks(counts, wide):
        width = channels.stop - channels.start
        size = count * len(index) * width
        block = streams[bits][used[bits] : used[bits] + size]
        if block.numel() != size:
            raise ValueError(f"{bits}-bit codes end before the keyframes they hold")
        used[bits] += size
        position = torch.searchsorted((counts == count).nonzero().flatten(), index)
        values = (
            low[index, channels] + span[index, channels] * block.reshape(count, len(index), width) / CODE_LEVELS[bits]
        )
        groups[count][:, position, channels] = values
    if any(used[bits] != streams[bits].numel() for bits in used):
        raise ValueError("more codes than the keyframes hold")
    return Tracks(counts, [((counts == count).nonzero().flatten(), keyframes) for count, keyframes in groups.items()])


def row_codes(values: torch.Tensor) -> dict[str, torch.Tensor]:
    """values [N, ...] as 8-bit codes of each row's own range: low and span float16 [N] (the span
    rounded up, so that the highest value still has a code), codes uint8 [N, ...]."""
    flat = values.detach().float().cpu().reshape(values.shape[0], -1)
    low = (flat.amin(1) if flat.shape[1] else torch.zeros(flat.shape[0])).to(torch.float16)
    high = flat.amax(1) if flat.shape[1] else torch.zeros(flat.shape[0])
    span = ((high - low.float()) * (1 + 2**-10)).clamp_min(0).to(torch.float16)
    scale = torch.where(span > 0, span.float(), torch.ones(len(span)))
    codes = ((flat - low.float()[:, None]) / scale[:, None] * CODE_LEVELS[8]).round().clamp(0, CODE_LEVELS[8])
    return {"low": low, "span": span, "codes": codes.to(torch.uint8).reshape(values.shape)}


def from_row_codes(stored: dict[str, torch.Tensor]) -> torch.Tensor:
    """row_codes()'s values, float32."""
    codes = stored["codes"].float()
    shape = (-1,) + (1,) * (codes.ndim - 1)
    return stored["low"].float().reshape(shape) + stored["span"].float().reshape(shape) * codes / CODE_LEVELS[8]
