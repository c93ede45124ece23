"""Explicit per-Gaussian motion: keyframes at uniform times and their interpolation.

A keyframe holds, for every Gaussian, the deformed state the field gives at that time, in the
rasteriser's terms: position [3], unit quaternion wxyz [4] (sign-aligned with the keyframe
before it, so that interpolating components follows the short arc) and scale [3] (the field's
std-devs, signed as the field leaves them; the rasteriser squares them). Between keyframes
every channel follows a uniform Catmull-Rom spline (cubic Hermite with central-difference
tangents; the two end segments use a mirrored phantom keyframe), and the quaternion is
renormalised: a cubic nlerp. The same few lines run in the web player (bake/web).
"""

from __future__ import annotations

import torch

POSITION = slice(0, 3)
QUATERNION = slice(3, 7)
SCALE = slice(7, 10)
CHANNELS = 10


def count_ladder(first: int, most: int) -> list[int]:
    """1, then `first` doubled as 2K - 1 (every time of K uniform times stays one of the next count's)
    up to `most`: the counts a Gaussian's keyframes (or splatv pieces) are chosen from."""
    counts = [1] + ([first] if first <= most and first > 1 else [])
    while len(counts) > 1 and 2 * counts[-1] - 1 <= most:
        counts.append(2 * counts[-1] - 1)
    return counts


def keyframe_times(count: int) -> torch.Tensor:
    """`count` uniform times covering [0, 1], the capture's normalised time range."""
    return torch.linspace(0.0, 1.0, count, dtype=torch.float64)


def pack_keyframe(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """[N, CHANNELS]: position, unit quaternion, scale."""
    return torch.cat([means, torch.nn.functional.normalize(quats, dim=-1), scales], dim=-1)


def align_quaternion_signs(keyframes: torch.Tensor) -> torch.Tensor:
    """q and -q are one rotation: flip each keyframe's quaternion to the hemisphere of the one before."""
    keyframes = keyframes.clone()
    for k in range(1, keyframes.shape[0]):
        dot = (keyframes[k, :, QUATERNION] * keyframes[k - 1, :, QUATERNION]).sum(-1, keepdim=True)
        keyframes[k, :, QUATERNION] *= torch.where(dot < 0, -1.0, 1.0)
    return keyframes


def spline_weights(count: int, time: float) -> tuple[int, list[float]]:
    """The first keyframe and the Catmull-Rom weights of the (up to) four keyframes around `time`
    (clamped to [0, 1]) among `count` at keyframe_times(count); a mirrored phantom keyframe
    (p0 = 2 p1 - p2 at the start, p3 = 2 p2 - p1 at the end) is folded into the weights of the two
    it is made of. One keyframe: weight 1 (a Gaussian that does not move)."""
    if count == 1:
        return 0, [1.0]
    u = min(max(float(time), 0.0), 1.0) * (count - 1)
    i = min(int(u), count - 2)
    f = u - i
    f2, f3 = f * f, f * f * f
    w0, w1, w2, w3 = 0.5 * (2 * f2 - f - f3), 0.5 * (2 - 5 * f2 + 3 * f3), 0.5 * (f + 4 * f2 - 3 * f3), 0.5 * (f3 - f2)
    first = i - 1
    if i == 0:
        w1, w2, w0, first = w1 + 2 * w0, w2 - w0, None, i
    if i + 2 == count:
        w1, w2, w3 = w1 - w3, w2 + 2 * w3, None
    return first, [w for w in (w0, w1, w2, w3) if w is not None]


def interpolation_matrix(count: int, times: torch.Tensor) -> torch.Tensor:
    """[len(times), count] float64: row i holds the spline's weights at times[i], so that
    matrix @ keyframes gives the (unnormalised) states at every time at once."""
    matrix = torch.zeros(len(times), count, dtype=torch.float64)
    for row, time in enumerate(times.tolist()):
        first, weights = spline_weights(count, time)
        matrix[row, first : first + len(weights)] = torch.tensor(weights, dtype=torch.float64)
    return matrix


def interpolate(keyframes: torch.Tensor, time: float) -> torch.Tensor:
    """The state [N, CHANNELS] at `time` (clamped to [0, 1]) from keyframes [K, N, CHANNELS] at
    keyframe_times(K); quaternions come out unit length.

    The spline is a weighted sum of the (up to) four keyframes around `time` (spline_weights): one
    matrix-vector product over contiguous keyframes, where the spelled-out polynomial took 17
    tensor operations (tests/test_bake.py holds the two equal).
    """
    if keyframes.shape[0] == 1:
        state = keyframes[0].clone()
        state[:, QUATERNION] = torch.nn.functional.normalize(state[:, QUATERNION], dim=-1)
        return state
    first, weights = spline_weights(keyframes.shape[0], time)
    span = keyframes[first : first + len(weights)]
    weights = torch.tensor(weights, dtype=keyframes.dtype, device=span.device)
    state = (weights @ span.reshape(len(weights), -1)).reshape(span.shape[1:])
    state[:, QUATERNION] = torch.nn.functional.normalize(state[:, QUATERNION], dim=-1)
    return state


def state_error(
    baked: torch.Tensor, truth: torch.Tensor, floor: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per Gaussian: (relative error, position error in scene units) of `baked` against `truth`
    ([..., N, CHANNELS] each).

    The relative error is the largest of the position error and the largest scale error, both
    as a fraction of the Gaussian's largest axis in `truth`, and of the rotation error in radians
    (the angle between the two orientations). With `floor` [N], a Gaussian's size counts as at
    least its floor (distil: the width of a pixel at the Gaussian).
    """
    size = truth[..., SCALE].abs().amax(-1)
    size = (size if floor is None else torch.maximum(size, floor)).clamp_min(1e-12)
    position = (baked[..., POSITION] - truth[..., POSITION]).norm(dim=-1)
    scale = (baked[..., SCALE].abs() - truth[..., SCALE].abs()).abs().amax(-1)
    cosine = (baked[..., QUATERNION] * truth[..., QUATERNION]).sum(-1).abs().clamp(max=1.0)
    angle = 2 * torch.acos(cosine)
    return torch.maximum(torch.maximum(position / size, scale / size), angle), position
