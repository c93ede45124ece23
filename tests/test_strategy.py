import copy
import math

import torch
from gsplat.strategy import ops as gsplat_ops

from liquidgs.gaussians import PARAM_KEYS, init_random_box
from liquidgs.train.strategy import D3DGSStrategy, DensifyConfig, _duplicate_unmeasured, _split


def make_setup(n=6, extent=1.0):
    params = init_random_box(n, 1.3, sh_degree=1, seed=0)
    with torch.no_grad():
        params["scales"].fill_(math.log(0.005))  # small: clone candidates
        params["scales"][n // 2 :] = math.log(0.05)  # large: split candidates
        params["opacities"].fill_(0.0)
    optimizers = {k: torch.optim.Adam([params[k]], lr=1e-3, eps=1e-15) for k in PARAM_KEYS}
    # One real Adam step so that every parameter has moments to carry.
    sum(p.sum() for p in params.values()).backward()
    for opt in optimizers.values():
        opt.step()
        opt.zero_grad()
    return params, optimizers


def make_info(grad_px: torch.Tensor, radii: torch.Tensor, width=100, height=100):
    means2d = torch.zeros_like(grad_px)
    means2d.grad = grad_px.clone()
    means2d.absgrad = grad_px.abs().clone()
    return {"means2d": means2d, "radii": radii, "width": width, "height": height}


def test_clone_small_split_large_and_carry_moments():
    params, optimizers = make_setup()
    strategy = D3DGSStrategy(DensifyConfig(grad_threshold=0.0007, start=0, interval=100), scene_extent=1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    # NDC gradient = pixel gradient * width/2 = 0.001 >= 0.0007 for the first two of each half.
    grad = torch.zeros(6, 2)
    grad[[0, 1, 3, 4], 0] = 0.001 / 50
    info = make_info(grad, torch.full((6,), 3))
    old_means = params["means"].detach().clone()
    old_scales = torch.exp(params["scales"].detach())
    report = strategy.step_post_backward(params, optimizers, state, step=100, info=info)
    assert report["cloned"] == 2 and report["split"] == 2 and report["pruned"] == 0
    n = params["means"].shape[0]
    assert n == 6 + 2 + 2 * 2 - 2  # clones appended, each split Gaussian replaced by two
    # Clones are exact copies (appended at 6, 7, then shifted down by the removal of the two
    # split originals); split children are smaller by 1.6.
    assert torch.equal(params["means"][4].detach(), old_means[0])
    assert torch.equal(params["means"][5].detach(), old_means[1])
    assert torch.allclose(torch.exp(params["scales"][-1].detach()), old_scales[4] / 1.6)
    for key in PARAM_KEYS:
        opt = optimizers[key]
        assert opt.param_groups[0]["params"][0] is params[key]
        moments = opt.state[params[key]]
        assert moments["exp_avg"].shape == params[key].shape
    # New Gaussians start with zero moments, kept ones keep theirs.
    assert optimizers["means"].state[params["means"]]["exp_avg"][-1].abs().sum() == 0
    assert optimizers["means"].state[params["means"]]["exp_avg"][0].abs().sum() > 0
    assert state["grad_accum"].shape == (n,) and state["grad_accum"].sum() == 0


def test_standard_gradient_mode_uses_grad_not_absgrad():
    params, optimizers = make_setup()
    strategy = D3DGSStrategy(DensifyConfig(gradient="standard", grad_threshold=0.0002, start=0), 1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    info = make_info(torch.zeros(6, 2), torch.full((6,), 3))
    info["means2d"].absgrad = torch.ones(6, 2)  # would densify everything if it were read
    report = strategy.step_post_backward(params, optimizers, state, step=100, info=info)
    assert report["cloned"] == report["split"] == 0


def test_prune_low_opacity_and_oversized_after_reset_interval():
    params, optimizers = make_setup()
    with torch.no_grad():
        params["opacities"][0] = torch.logit(torch.tensor(0.001))
    strategy = D3DGSStrategy(DensifyConfig(start=0, opacity_reset_interval=3000, max_world_size=0.04), 1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    radii = torch.tensor([3, 3, 25, 3, 3, 3])
    before = strategy.step_post_backward(params, optimizers, state, step=100, info=make_info(torch.zeros(6, 2), radii))
    assert before["pruned"] == 1  # only opacity before the reset interval
    state = strategy.initial_state(5, torch.device("cpu"))
    radii = torch.tensor([3, 25, 3, 3, 3])
    after = strategy.step_post_backward(params, optimizers, state, step=3100, info=make_info(torch.zeros(5, 2), radii))
    # The 25 px one and the three 0.05-wide ones (> 0.04 * extent) go.
    assert after["pruned"] == 4 and params["means"].shape[0] == 1


def test_opacity_reset_actually_fires():
    params, optimizers = make_setup()
    with torch.no_grad():
        params["opacities"].fill_(3.0)
        params["opacities"][0] = torch.logit(torch.tensor(0.005))
    strategy = D3DGSStrategy(DensifyConfig(start=10_000, opacity_reset_interval=3000), 1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    report = strategy.step_post_backward(params, optimizers, state, 3000, make_info(torch.zeros(6, 2), torch.ones(6)))
    assert report["reset"] == 1
    opacity = torch.sigmoid(params["opacities"])
    assert torch.allclose(opacity[1:], torch.full((5,), 0.01), atol=1e-6)
    assert opacity[0] < 0.01  # min(opacity, 0.01), not a blanket set
    assert optimizers["opacities"].state[params["opacities"]]["exp_avg"].abs().sum() == 0
    # After the densification window nothing happens, not even a reset.
    late = strategy.step_post_backward(params, optimizers, state, 15_000, make_info(torch.zeros(6, 2), torch.ones(6)))
    assert late == {"cloned": 0, "split": 0, "pruned": 0, "reset": 0, "pruned_all": 0}


def test_adam_steps_after_densification():
    params, optimizers = make_setup()
    strategy = D3DGSStrategy(DensifyConfig(start=0), 1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    grad = torch.full((6, 2), 1.0)
    strategy.step_post_backward(params, optimizers, state, 100, make_info(grad, torch.full((6,), 3)))
    loss = sum((p**2).sum() for p in params.values())
    loss.backward()
    before = params["means"].detach().clone()
    for opt in optimizers.values():
        opt.step()
    assert not torch.equal(before, params["means"].detach())


# gsplat.strategy.ops does the strategy's bookkeeping; these pin what D-3DGS needs from it and
# the two places it differs, so a gsplat release that changes an op fails here, not in training.


def copy_setup(params, optimizers):
    """An independent copy of make_setup's parameters and Adam states."""
    twin = torch.nn.ParameterDict({k: torch.nn.Parameter(v.detach().clone()) for k, v in params.items()})
    twin_optimizers = {}
    for key in PARAM_KEYS:
        twin_optimizers[key] = torch.optim.Adam([twin[key]], lr=1e-3, eps=1e-15)
        twin_optimizers[key].load_state_dict(copy.deepcopy(optimizers[key].state_dict()))
    return twin, twin_optimizers


def measured_state(n):
    return {
        key: torch.arange(1.0, n + 1) * scale for key, scale in (("grad_accum", 0.1), ("count", 1), ("max_radii", 7))
    }


def moments(optimizers, params, key):
    return optimizers[key].state[params[key]]


def test_clone_appends_copies_with_zero_moments_and_unmeasured_statistics():
    params, optimizers = make_setup()
    before, before_optimizers = copy_setup(params, optimizers)
    state = measured_state(6)
    mask = torch.tensor([True, False, False, True, False, False])
    _duplicate_unmeasured(params, optimizers, state, mask)
    for key in PARAM_KEYS:
        assert torch.equal(params[key], torch.cat([before[key], before[key][mask]]))
        assert optimizers[key].param_groups[0]["params"] == [params[key]]
        old, new = moments(before_optimizers, before, key), moments(optimizers, params, key)
        assert torch.equal(new["step"], old["step"])
        for name in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(new[name], torch.cat([old[name], torch.zeros_like(old[name][mask])]))
    for key, value in measured_state(6).items():
        # gsplat's duplicate would give the copies their sources' statistics.
        assert torch.equal(state[key], torch.cat([value, torch.zeros(2)]))


def test_remove_keeps_the_others_rows_moments_and_statistics():
    params, optimizers = make_setup()
    before, before_optimizers = copy_setup(params, optimizers)
    state = measured_state(6)
    mask = torch.tensor([False, True, True, False, False, True])
    gsplat_ops.remove(params, optimizers, state, mask)
    for key in PARAM_KEYS:
        assert torch.equal(params[key], before[key][~mask])
        old, new = moments(before_optimizers, before, key), moments(optimizers, params, key)
        assert torch.equal(new["step"], old["step"])
        for name in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(new[name], old[name][~mask])
    for key, value in measured_state(6).items():
        assert torch.equal(state[key], value[~mask])


def test_split_is_gsplats_split_given_the_same_draws_but_with_unmeasured_children():
    params, optimizers = make_setup()
    theirs, their_optimizers = copy_setup(params, optimizers)
    state, their_state = measured_state(6), measured_state(6)
    mask = torch.tensor([False, True, False, True, True, False])
    _split(params, optimizers, state, mask, count=2, generator=torch.Generator().manual_seed(7))
    torch.manual_seed(7)  # gsplat draws the same standard normals from the global generator
    gsplat_ops.split(theirs, their_optimizers, their_state, mask)
    for key in PARAM_KEYS:
        assert params[key].shape == theirs[key].shape
        if key == "means":  # the same draws, rotated by a different product
            assert torch.allclose(params[key], theirs[key], atol=1e-6)
        else:
            assert torch.equal(params[key], theirs[key]), key
        ours, gsplats = moments(optimizers, params, key), moments(their_optimizers, theirs, key)
        assert ours.keys() == gsplats.keys()
        for name in ours:
            assert torch.equal(ours[name], gsplats[name]), (key, name)
    kept = int((~mask).sum())
    for key in state:
        assert torch.equal(state[key][:kept], their_state[key][:kept])
        assert not state[key][kept:].any() and their_state[key][kept:].all()


def test_split_count_is_a_setting_and_the_scale_divisor_follows_it():
    params, optimizers = make_setup()
    before = torch.exp(params["scales"].detach()[[4]])
    _split(params, optimizers, measured_state(6), torch.tensor([False] * 4 + [True, False]), count=3, generator=None)
    assert params["means"].shape[0] == 6 - 1 + 3
    assert torch.equal(torch.exp(params["scales"].detach()[-3:]), torch.exp(torch.log(before / 2.4)).repeat(3, 1))
