import math

import torch

from liquidgs.gaussians import PARAM_KEYS, init_random_box
from liquidgs.train.strategy import D3DGSStrategy, DensifyConfig


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
