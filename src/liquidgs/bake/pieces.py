"""splaTV's model fitted to a motion, with as many temporal pieces per Gaussian as its motion needs.

A splatv record holds one cubic of the position and one line of the rotation in dt = t - c, and
an opacity window exp(-(dt / s)^2) (bake/formats.py). One record per Gaussian over the whole
capture (c = 0.5, s flat) keeps a slow motion; a swing needs more. A Gaussian of P > 1 pieces
becomes P records with centres c_j = j / (P - 1) and a common temporal scale s = WINDOW / (P - 1),
each fitted by least squares weighted by its own window to the motion sampled at SAMPLES times,
so that wherever a piece is visible its cubic follows the motion there. The players skip a record
whose window is under PLAYER_CUT; overlapping pieces composite as splats do, so each piece's
opacity is chosen so that the pieces together cover, averaged over the capture, what the
Gaussian covered alone.

Pieces are chosen per Gaussian on the ladder 1, 2, 3, 5, 9, ... MAX_PIECES: the first whose every
visible piece stays within the budget at every sample time, position error as a fraction of the
Gaussian's largest axis (counted as at least PIXEL_FLOOR pixel widths in the camera that sees it
finest, as the bake counts it), rotation error in radians. Given each Gaussian's share of the
rendered pixels (pixel_weights), the budget is weighted by it (IMPORTANCE_QUANTILE): the pieces go to
the Gaussians that make the picture. The export's default, fit_within_bytes, tries a few budgets and
keeps the one closest to the run on train views within MOST_RECORDS records per Gaussian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from liquidgs.bake.distil import pixel_widths, sample_field
from liquidgs.bake.formats import PLAYER_CUT, TEMPORAL_CENTRE, TEMPORAL_SCALE, SplatvModel
from liquidgs.bake.motion import POSITION, QUATERNION, SCALE, align_quaternion_signs, count_ladder, keyframe_times
from liquidgs.eval.metrics import psnr
from liquidgs.sh import SH_C0, eval_sh
from liquidgs.train.model import render_frame

SAMPLES = 129
WINDOW = 0.7
"""Temporal scale in units of the spacing between centres. Overlapping copies of one Gaussian
composite as two splats, not as one (1 - (1 - a g)(1 - b g) is not (a + b) g across the splat's
profile g), so the overlap costs; too little overlap leaves the Gaussian faint between centres.
On a swinging sheet of opaque Gaussians (tests/test_splatv_player.py) liquidgs' render of the file
scored 26.3-27.4 dB against the motion at 1.0 (exp(-1) at the next centre), 34.0-37.3 at 0.7,
29.7-33.4 at 0.55, 17.3-36.6 at 0.4."""
TOLERANCE = 0.5
"""fit_splatv's budget where none is given (the export's before the weighted budgets)."""
PIXEL_FLOOR = 4.0
MAX_PIECES = 17
IMPORTANCE_QUANTILE = 0.9
"""With pixel shares, a Gaussian whose share is at least this quantile of the run's is held to the
tolerance, one with a share c below that reference r to tolerance x sqrt(r / c): a small move's
squared image error grows with the pixels the Gaussian covers, so this spreads the error over what
shows. The shares are skewed: on the demo's MLP 8% of the Gaussians hold half the pixel weight and
33% hold 90% (the cat's CfC: 6% and 37%). At equal records the weighted fit was 2.9 dB closer to
the field on the demo's MLP (39.7 dB at 4.4 records per Gaussian against 36.8 at 5.4 unweighted) and
1.0 dB on the cat's CfC; square root against the share itself: 39.7 against 37.6 dB (3.2 records)
and 38.8 (4.2) at tolerances 0.15 and 0.1 (docs/results/sharing.md)."""
LOOSE_TOLERANCES = (0.5, 0.3)
"""Budgets fit_within_bytes always scores: more records are not always closer, as two overlapping
pieces composite as two splats (on hellwarrior 0.5, 1.2 records per Gaussian, scored 44.5 dB against
the field, 0.15 with 5.4 records 39.2)."""
TIGHTEST_TOLERANCE = 0.05
BISECTIONS = 4
"""Halvings of log(tolerance) between TIGHTEST_TOLERANCE and the tightest loose budget within bytes
that find the tightest budget within MOST_RECORDS records per Gaussian (to about 11%)."""
AUTO_WINDOWS = (0.55, 0.6, WINDOW)
"""The windows fit_within_bytes tries. The opaque sheet's swing chose WINDOW; trained motion fits
closer with narrower ones (the tightest budget within 4 records per Gaussian for each): the demo's
MLP 40.1 dB against the field at 0.55, 40.2 at 0.6 (4.1 records: over), 39.5 at 0.7; its CfC 40.2 at
0.55, 39.3 at 0.7; the cat's MLP 39.9 at 0.55, 40.2 at 0.6, 39.4 at 0.7."""
MOST_RECORDS = 4.0
"""The most records per Gaussian fit_within_bytes keeps: the file at most 4x the bytes of one record
per Gaussian (the export before temporal pieces)."""
SELECTION_VIEWS = 8
"""Train views (evenly spaced) fit_within_bytes scores each budget on; the test views stay for the
export's report."""


@dataclass
class Fitted:
    model: SplatvModel
    motion_kept: float | None
    """1 - (squared position residual) / (squared position deviation from each Gaussian's mean
    position) of the pieces' opacity-weighted position, over the samples; None where no Gaussian moves."""
    report: dict


def windows(pieces: int, times: torch.Tensor, width: float = WINDOW) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Centres [P], the windows [S, P] at `times` as the players show them (0 under PLAYER_CUT), the
    scale (`width` times the spacing between centres)."""
    if pieces == 1:
        centres, scale = torch.tensor([TEMPORAL_CENTRE], dtype=torch.float64), TEMPORAL_SCALE
    else:
        centres, scale = torch.linspace(0.0, 1.0, pieces, dtype=torch.float64), width / (pieces - 1)
    window = torch.exp(-(((times[:, None] - centres[None, :]) / scale) ** 2))
    return centres, torch.where(window < PLAYER_CUT, torch.zeros_like(window), window), scale


def weighted_fit(dt: torch.Tensor, weight: torch.Tensor, values: torch.Tensor, degree: int) -> torch.Tensor:
    """Coefficients [degree + 1, M] of the polynomial in dt [S] fitting values [S, M] by least
    squares weighted by weight [S]."""
    basis = torch.stack([dt**k for k in range(degree + 1)], dim=1)
    root = weight.sqrt()[:, None]
    return torch.linalg.lstsq(root * basis, root * values).solution


def float16_fit(dt: torch.Tensor, weight: torch.Tensor, values: torch.Tensor, degree: int) -> torch.Tensor:
    """weighted_fit with the coefficients the file stores in float16 (all but a position's constant
    term) rounded as it rounds them, highest first, each lower one refitted to what is left: a
    short piece's cubic term can be large, and its rounding alone would move the Gaussian."""
    coefficients = weighted_fit(dt, weight, values, degree)
    rest = values.clone()
    for k in range(degree, 0, -1):
        coefficients[k] = coefficients[k].to(torch.float16).to(coefficients.dtype)
        rest = rest - dt[:, None] ** k * coefficients[k]
        coefficients[:k] = weighted_fit(dt, weight, rest, k - 1)
    return coefficients


def piece_errors(states, centres, window, floor):
    """Per piece: position [4, n, 3] and rotation [2, n, 4] coefficients, and per Gaussian the
    largest relative error [n] of any piece at any sample time it is visible."""
    times = keyframe_times(states.shape[0])
    n = states.shape[1]
    size = torch.maximum(states[..., SCALE].abs().amax(-1), floor).clamp_min(1e-12)
    worst = torch.zeros(n, dtype=torch.float64)
    pieces = []
    for j, centre in enumerate(centres.tolist()):
        dt = times - centre
        weight = window[:, j]
        positions = states[..., POSITION].reshape(len(times), -1)
        position = float16_fit(dt, weight, positions, 3)
        rotation = float16_fit(dt, weight, states[..., QUATERNION].reshape(len(times), -1), 1)
        rotation[0] = rotation[0].to(torch.float16).to(rotation.dtype)  # the file's rotation is float16 too
        basis = torch.stack([dt**k for k in range(4)], dim=1)
        fitted = (basis @ position).reshape(len(times), n, 3)
        quats = torch.nn.functional.normalize((basis[:, :2] @ rotation).reshape(len(times), n, 4), dim=-1)
        error = (fitted - states[..., POSITION]).norm(dim=-1) / size
        angle = 2 * torch.acos((quats * states[..., QUATERNION]).sum(-1).abs().clamp(max=1.0))
        # A piece is judged where it shows, by how much it shows: at a tenth of its opacity a stray
        # copy shows a tenth as much.
        worst = torch.maximum(worst, (weight[:, None] * torch.maximum(error, angle)).amax(0))
        pieces.append((position.reshape(4, n, 3), rotation.reshape(2, n, 4)))
    return pieces, worst


def piece_opacity(opacity: torch.Tensor, window: torch.Tensor) -> torch.Tensor:
    """[n, P]: the opacity of each of a Gaussian's pieces. The windows' least-squares partition of
    one, m [P] (sum_j m_j w_j(t) ~ 1: the end pieces, with one neighbour, weigh more), scaled by
    lam per Gaussian so that 1 - prod_j (1 - min(lam m_j, 1) w_j(t)), averaged over the sample
    times, is the Gaussian's opacity (bisection)."""
    ones = torch.ones(window.shape[0], 1, dtype=window.dtype)
    share = torch.linalg.lstsq(window, ones).solution.flatten().clamp_min(1e-3)
    low, high = torch.zeros_like(opacity), torch.full_like(opacity, 1.0 / float(share.min()))
    for _ in range(40):
        middle = (low + high) / 2
        pieces = (middle[:, None] * share[None]).clamp(max=1.0)
        cover = 1 - torch.prod(1 - pieces[:, None, :] * window[None], dim=-1)
        below = cover.mean(-1) < opacity
        low, high = torch.where(below, middle, low), torch.where(below, high, middle)
    return (((low + high) / 2)[:, None] * share[None]).clamp(max=1.0)


def seen_colour(run, positions: torch.Tensor, cameras, weights: torch.Tensor | None = None) -> torch.Tensor:
    """[n, 3] in [0, 1]: the colour each Gaussian shows, averaged over the cameras' views of it
    (splatv holds one colour, no view dependence) - with `weights` (pixel_weights at `cameras`) each
    view by how much of it the Gaussian makes, evenly where it makes none - or its SH degree-0 colour
    without cameras. Weighted, the demo's MLP file scored 0.3 dB closer to the field."""
    if not len(cameras):
        return (run.params["sh0"].detach().cpu().double()[:, 0] * SH_C0 + 0.5).clamp(0, 1)
    sh = torch.cat([run.params["sh0"], run.params["shN"]], dim=1).detach().cpu().double()
    even = torch.full((len(cameras), positions.shape[0]), 1.0 / len(cameras), dtype=torch.float64)
    if weights is not None:
        seen = weights.sum(0)
        even = torch.where(seen > 0, weights / seen.clamp_min(1e-300), even)
    total = torch.zeros(positions.shape[0], 3, dtype=torch.float64)
    for camera, share in zip(cameras, even, strict=True):
        centre = torch.linalg.inv(camera.viewmat.double().cpu())[:3, 3]
        total += share[:, None] * (eval_sh(run.sh_degree, sh, positions - centre) + 0.5).clamp(0, 1)
    return total


def pixel_weights(run, frames, background: torch.Tensor) -> torch.Tensor:
    """[F, n] float64: each Gaussian's compositing weight summed over every pixel of each of `frames`
    (at its camera and time); summed over the frames, its pixel share. The rasteriser composites extra
    feature channels with colour's weights, so a row is the gradient of the composited sum of a
    channel of ones with respect to each Gaussian's one."""
    n = run.params["opacities"].shape[0]
    rows = []
    for frame in frames:
        with torch.no_grad():
            gaussians = run.at_time(frame.time)
        with torch.enable_grad():  # a caller's no_grad (bench bake) would leave nothing to differentiate
            ones = torch.ones(n, 1, device=gaussians.means.device, requires_grad=True)
            shown = render_frame(gaussians, frame.camera, sh_degree=0, background=background,
                                 backend=run.config.backend, features=ones)  # fmt: skip
            (weight,) = torch.autograd.grad(shown.features.sum(), ones)
        rows.append(weight.flatten().detach().cpu().double())
    return torch.stack(rows) if rows else torch.zeros(0, n, dtype=torch.float64)


def weighted_budget(tolerance: float, shares: torch.Tensor | None, n: int) -> torch.Tensor:
    """[n] each Gaussian's budget: `tolerance`, loosened by its pixel share [n] (IMPORTANCE_QUANTILE)."""
    budget = torch.full((n,), float(tolerance), dtype=torch.float64)
    if shares is None:
        return budget
    reference = float(shares.quantile(IMPORTANCE_QUANTILE))
    if reference <= 0:  # hardly anything shows: nothing to weigh by
        return budget
    return budget * (reference / shares.clamp_min(reference * 1e-12)).clamp(min=1.0).sqrt()


def fit_within_bytes(run, frames, train, background: torch.Tensor, most: int = MAX_PIECES) -> Fitted:
    """The export's fit: weighted by pixel shares over `frames`, for each of AUTO_WINDOWS the
    LOOSE_TOLERANCES and the tightest budget within MOST_RECORDS records per Gaussian (bisected); of
    those, the one whose render is closest to the run's on SELECTION_VIEWS of the `train` frames
    (where even the loosest is over, the first fitted). The report names the window and tolerance
    kept and every fit tried, with its records and, where scored, its score."""
    picks = torch.linspace(0, len(train) - 1, min(SELECTION_VIEWS, len(train))).round().long().unique()
    selection = [train[int(i)] for i in picks]
    cameras = [f.camera for f in frames]
    weights = pixel_weights(run, frames, background)
    motion = sampled_motion(run, cameras, weights)  # the field sampled once for every fit below
    n = weights.shape[1]
    kept, tried = None, []

    def attempt(width: float, tolerance: float) -> tuple[Fitted, dict] | None:
        """The fit and its record in `tried`, where within bytes; None where over."""
        nonlocal kept
        fitted = fit_splatv(run, cameras, tolerance, most, weights, width, motion)
        record = {"window": width, "tolerance": tolerance, "records": fitted.report["records"], "train_views_db": None}
        tried.append(record)
        if kept is None:  # where every fit is over, the first
            kept = (-math.inf, fitted)
        return (fitted, record) if fitted.report["records"] <= MOST_RECORDS * n else None

    def score(fitted: Fitted, record: dict) -> None:
        nonlocal kept
        record["train_views_db"] = sum(agreement(run, fitted.model, selection, background)) / len(selection)
        if record["train_views_db"] > kept[0]:
            kept = (record["train_views_db"], fitted)

    for width in AUTO_WINDOWS:
        loose = [(t, fit) for t in LOOSE_TOLERANCES if (fit := attempt(width, t)) is not None]
        for _, fit in loose:
            score(*fit)
        if not loose:  # even the loosest is over
            continue
        (tolerance, tightest), over = min(loose, key=lambda pair: pair[0]), TIGHTEST_TOLERANCE
        for _ in range(BISECTIONS):
            middle = math.sqrt(tolerance * over)
            fit = attempt(width, middle)
            (tolerance, tightest), over = ((middle, fit), over) if fit is not None else ((tolerance, tightest), middle)
        if tolerance not in LOOSE_TOLERANCES:
            score(*tightest)
    kept[1].report["tried"] = tried
    return kept[1]


def motion_kept(deviation: torch.Tensor, residual: torch.Tensor, shares: torch.Tensor | None) -> float | None:
    """1 - squared residual / squared deviation ([S, n, 3] each), summed over the samples and the
    Gaussians, each Gaussian weighted by its pixel share where `shares` are given; None where nothing
    moves."""
    weight = torch.ones(deviation.shape[1], dtype=torch.float64) if shares is None else shares.double()
    moved = float(((deviation**2).sum((0, 2)) * weight).sum())
    lost = float(((residual**2).sum((0, 2)) * weight).sum())
    return min(max(1.0 - lost / moved, 0.0), 1.0) if moved > 0 else None


@dataclass
class SampledMotion:
    """What fit_splatv reads of a run before choosing pieces, the same for every budget and window."""

    times: torch.Tensor  # [S]
    states: torch.Tensor  # [S, n, channels] float64, quaternion signs aligned
    floor: torch.Tensor  # [n] PIXEL_FLOOR pixel widths in the camera that sees each finest
    opacity: torch.Tensor  # [n]
    rgb: torch.Tensor  # [n, 3] seen_colour


def sampled_motion(run, cameras=(), weights: torch.Tensor | None = None) -> SampledMotion:
    times = keyframe_times(SAMPLES)
    states = align_quaternion_signs(sample_field(run, times).cpu()).double()
    middle = states[SAMPLES // 2, :, POSITION]
    floor = (
        PIXEL_FLOOR * pixel_widths(cameras, middle.float()).clamp(max=1e30).double()
        if len(cameras)
        else torch.zeros(states.shape[1], dtype=torch.float64)
    )
    opacity = torch.sigmoid(run.params["opacities"].detach().cpu().double()).flatten()
    return SampledMotion(times, states, floor, opacity, seen_colour(run, middle, cameras, weights))


def fit_splatv(
    run,
    cameras=(),
    tolerance: float = TOLERANCE,
    most: int = MAX_PIECES,
    weights: torch.Tensor | None = None,
    width: float = WINDOW,
    motion: SampledMotion | None = None,
) -> Fitted:
    """The pieces fitted to the run's motion within `tolerance` for every Gaussian, or, with `weights`
    (pixel_weights at `cameras`), within a budget weighted by each Gaussian's pixel share and with
    its colour weighted by how much of each view it makes; pieces' windows `width` times the
    spacing between their centres. `motion`: sampled_motion(run, cameras, weights), where the caller
    fits the same run more than once."""
    motion = motion if motion is not None else sampled_motion(run, cameras, weights)
    times, states, floor, opacity, rgb = motion.times, motion.states, motion.floor, motion.opacity, motion.rgb
    n = states.shape[1]
    shares = None if weights is None else weights.sum(0)
    budget = weighted_budget(tolerance, shares, n)
    counts = torch.full((n,), 0, dtype=torch.long)
    steps = count_ladder(2, most)
    records, blended, errors = [], torch.zeros(SAMPLES, n, 3, dtype=torch.float64), torch.zeros(n, dtype=torch.float64)
    for pieces in steps:
        index = (counts == 0).nonzero().flatten()
        if not len(index):
            break
        centres, window, scale = windows(pieces, times, width)
        part = states[:, index]
        fitted, worst = piece_errors(part, centres, window, floor[index])
        settled = worst <= budget[index] if pieces != steps[-1] else torch.ones_like(worst, dtype=torch.bool)
        chosen = index[settled]
        counts[chosen] = pieces
        errors[chosen] = worst[settled]
        share = piece_opacity(opacity[chosen], window) if pieces > 1 else opacity[chosen][:, None]
        shown = torch.zeros(SAMPLES, len(chosen), dtype=torch.float64)
        for j, (position, rotation) in enumerate(fitted):
            dt = times - centres[j]
            basis = torch.stack([dt**k for k in range(4)], dim=1)
            path = (basis @ position[:, settled].reshape(4, -1)).reshape(SAMPLES, -1, 3)
            w = window[:, j : j + 1] * share[None, :, j]
            blended[:, chosen] += w[..., None] * path
            shown += w
            records.append(
                SplatvModel(
                    position=position[0, settled].float(),
                    motion=torch.cat([position[1, settled], position[2, settled], position[3, settled]], 1).float(),
                    rotation=rotation[0, settled].float(),
                    omega=rotation[1, settled].float(),
                    scale=(
                        (window[:, j : j + 1, None] * part[:, settled][..., SCALE].abs()).sum(0)
                        / window[:, j].sum().clamp_min(1e-12)
                    ).float(),
                    rgb=rgb[chosen].float(),
                    opacity=share[:, j].float(),
                    temporal=torch.tensor([float(centres[j]), scale]).expand(len(chosen), 2).clone(),
                )
            )
        blended[:, chosen] /= shown.clamp_min(1e-12)[..., None]
    model = SplatvModel(*(torch.cat([getattr(r, f) for r in records]) for f in SplatvModel.__dataclass_fields__))
    deviation = states[..., POSITION] - states[..., POSITION].mean(0, keepdim=True)
    residual = blended - states[..., POSITION]
    kept = motion_kept(deviation, residual, None)
    report = {
        "tolerance": tolerance,
        "window": width,
        "weighted": weights is not None,
        "pieces": {str(p): int((counts == p).sum()) for p in steps if int((counts == p).sum())},
        "records": int(model.position.shape[0]),
        "max_relative_error": float(errors.max()) if n else 0.0,
        "gaussians_over_budget": int((errors > budget).sum()),
        "motion_kept_by_share": None if shares is None else motion_kept(deviation, residual, shares),
    }
    return Fitted(model, kept, report)


@torch.no_grad()
def agreement(run, model: SplatvModel, frames, background: torch.Tensor) -> list[float]:
    """PSNR (dB) of the splatv model's render against `run`'s (its field, or a baked scene) at each
    frame's camera and time; the model at SH degree 0, as the players show it."""
    scores = []
    for frame in frames:
        truth = run.render(frame.camera, frame.time, background).rgb.clamp(0, 1)
        g = model.at_time(frame.time)
        shown = render_frame(g, frame.camera, sh_degree=0, background=background, backend=run.config.backend)
        scores.append(float(psnr(shown.rgb.clamp(0, 1), truth)))
    return scores
