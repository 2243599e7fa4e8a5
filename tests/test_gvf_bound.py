"""`agent.gvf_bootstrap_bound`: the GVFs' bootstrapped v(s') clamped to +-max |c| seen
(learner.gvf.ReturnBound), where every (1 - gamma)-scaled return lies."""

import pytest
import torch

from learner.gvf import cumulants, expand_gammas, td_target
from tests.core_fixtures import lanedrive_data, make_core


@pytest.fixture(scope="module")
def data():
    return lanedrive_data()


def test_the_bound_leaves_possible_bootstraps_alone_and_clamps_the_rest():
    gammas = expand_gammas([0.5, 0.97], 2)
    c = cumulants({"alpha": torch.tensor([[0.4], [-0.9]]), "beta": torch.tensor([[1.0], [-2.0]])}, ["alpha", "beta"])
    terminated = torch.tensor([[False], [False]])
    bound = torch.tensor([1.0, 3.0])  # |alpha| <= 1, |beta| <= 3
    inside = torch.tensor([[0.2, -0.9, 2.5, -3.0], [1.0, 0.0, -1.0, 2.9]])
    assert torch.equal(td_target(c, terminated, inside, gammas, bound=bound), td_target(c, terminated, inside, gammas))
    wild = torch.tensor([[1e4, -1e4, 1e4, -1e4], [-50.0, 50.0, -50.0, 50.0]])
    y = td_target(c, terminated, wild, gammas, bound=bound)
    assert (y[:, :2].abs() <= 1.0 + 1e-6).all() and (y[:, 2:].abs() <= 3.0 + 1e-6).all()
    assert (td_target(c, terminated, wild, gammas).abs() > 20).all()  # unclamped they follow v(s')


def test_the_core_bound_is_the_largest_cumulant_seen(data):
    core = make_core("gvf_ddpg")
    core.add(data[:150])
    first = core.bound.max_abs.clone()
    core.add(data[150:])
    seen = torch.stack([data["next", name].abs().max() for name in ("alpha", "beta")])
    assert torch.allclose(core.bound.max_abs, seen) and (first <= core.bound.max_abs).all()
    resumed = make_core("gvf_ddpg")
    resumed.load_state_dict(core.state_dict())
    assert torch.equal(resumed.bound.max_abs, core.bound.max_abs)
    assert make_core("gvf_ddpg", gvf_bootstrap_bound=False).bound is None


def targets_of_a_diverged_gvf(bounded: bool, data, monkeypatch) -> torch.Tensor:
    """The TD targets of one update of a core whose GVF outputs were pushed to 30 (as a diverged
    GVF's are; the true values are within +-max |c|, about 1 for alpha)."""
    import learner.core

    seen = []

    def recording(*args, **kwargs):
        seen.append(td_target(*args, **kwargs))
        return seen[-1]

    monkeypatch.setattr(learner.core, "td_target", recording)
    core = make_core("gvf_ddpg", gvf_bootstrap_bound=bounded)
    core.add(data[:300])
    with torch.no_grad():
        core.nets.gvf.head[-1].bias.fill_(30.0)
    core.update_representation()
    return seen[-1], core


def test_a_diverged_gvfs_targets_stay_within_the_cumulants_range_with_the_bound(data, monkeypatch):
    target, core = targets_of_a_diverged_gvf(True, data, monkeypatch)
    n_gammas = len(core.agent.gammas)
    limit = core.bound.max_abs.repeat_interleave(n_gammas)
    assert (target.abs() <= limit + 1e-5).all()
    unbounded, _ = targets_of_a_diverged_gvf(False, data, monkeypatch)
    assert (unbounded[:, 1:n_gammas].abs() > 10).any()  # the paper's target follows v(s') = 30 out of range
