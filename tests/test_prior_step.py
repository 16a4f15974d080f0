"""The prior's training step (train.prior_step): the body term on given frames, the graphed
step's optimiser saved as a plain one, and, where a GPU is present, the CUDA graph against the
eager step and a graphed run resumed on the CPU."""

from __future__ import annotations

import json

import pytest
import torch

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.model.optim import clipped_step
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.model.state import VELOCITY_DIMS
from mdvae_cli.train.corpus import WindowSet
from mdvae_cli.train.prior_loss import prior_losses, spread_vertex_ids
from mdvae_cli.train.prior_step import PriorStep, graph_possible, make_capturable
from mdvae_cli.train.run_state import optimizer_from_tensors, optimizer_to_tensors
from mdvae_cli.train.train_prior import train_prior
from tests.test_prior import TINY, tiny_config, write_corpus

CUDA = torch.cuda.is_available()


def parts(device: str, batch: int = 6, T: int = 12, seed: int = 0):
    """A tiny prior (normaliser fitted), the built-in body, vertex ids and ``batch`` windows."""
    torch.manual_seed(seed)
    g = torch.Generator().manual_seed(seed)
    D = TINY.state_dim
    x0 = 0.2 * torch.randn(batch, D, generator=g)
    data = WindowSet(x0, 0.2 * torch.randn(batch, T, D, generator=g), torch.zeros(batch, 16))
    model = PriorModel(TINY)
    model.normalizer.fit(data.x0, data.x)
    body = BodyModel(load_body_model(None))
    ids = spread_vertex_ids(body.v_template.shape[0], 32)
    dev = torch.device(device)
    data = WindowSet(*(t.to(dev) for t in (data.x0, data.x, data.betas)))
    return model.to(dev), body.to(dev), ids.to(dev), data


def test_body_term_on_given_frames_equals_the_drawn_phase():
    model, body, ids, data = parts("cpu")
    args = (model, model.dvae, data, body, ids, 0.3, 2.0, 4, 30.0, 0.1)
    torch.manual_seed(5)
    drawn = prior_losses(*args)
    for phase in range(4):
        frames = torch.arange(phase, data.x.shape[1], 4)
        torch.manual_seed(5)
        given = prior_losses(*args[:5], torch.tensor(0.3), *args[6:], frames=frames,
                             velocity_dims=torch.as_tensor(VELOCITY_DIMS))  # fmt: skip
        # the encoder's noise is the same (seeded), and the terms that do not read the phase
        # agree exactly
        for name in ("recon", "kl"):
            assert torch.equal(given[name], drawn[name])
    # with the phase the eager step drew, the body term agrees too
    torch.manual_seed(5)
    model.dvae(model.normalizer.normalize(data.x), model.normalizer.normalize(data.x0))
    phase = int(torch.randint(4, (1,)))
    torch.manual_seed(5)
    given = prior_losses(*args[:5], torch.tensor(0.3), *args[6:],
                         frames=torch.arange(phase, data.x.shape[1], 4))  # fmt: skip
    for name in ("loss", "body_cm2"):
        assert torch.allclose(given[name], drawn[name], rtol=1e-6, atol=0)


def test_graph_possible_only_on_one_gpu_with_an_even_stride():
    assert not graph_possible(torch.device("cpu"), False, 60, 4)
    assert graph_possible(torch.device("cuda"), False, 60, 4)
    assert not graph_possible(torch.device("cuda"), True, 60, 4)
    assert not graph_possible(torch.device("cuda"), False, 62, 4)


def test_graphed_adam_is_saved_as_a_plain_one_and_resumes():
    model, body, ids, data = parts("cpu")
    opt = torch.optim.Adam(model.dvae.parameters(), lr=1e-3, foreach=False)
    terms = prior_losses(model, model.dvae, data, body, ids, 0.5, 2.0, 4, 30.0, 0.1)
    clipped_step(opt, terms["loss"], model.dvae.parameters(), 5.0)
    # what a graphed step leaves in the groups: the rate as a tensor, capturable on
    for group in opt.param_groups:
        group["lr"] = torch.tensor(2.5e-3)
        group["capturable"] = True
    tensors, groups = optimizer_to_tensors(opt)
    json.dumps(groups)  # JSON-able: the rate is a number again
    assert all(g["lr"] == pytest.approx(2.5e-3) for g in groups["param_groups"])
    assert all(g["capturable"] is False for g in groups["param_groups"])
    assert all(v.device.type == "cpu" for k, v in tensors.items() if k.endswith("/step"))
    fresh = torch.optim.Adam(model.dvae.parameters(), lr=1.0)
    fresh.load_state_dict(optimizer_from_tensors(tensors, groups))
    assert fresh.param_groups[0]["lr"] == pytest.approx(2.5e-3)
    before = [p.detach().clone() for p in model.dvae.parameters()]
    terms = prior_losses(model, model.dvae, data, body, ids, 0.5, 2.0, 4, 30.0, 0.1)
    clipped_step(fresh, terms["loss"], model.dvae.parameters(), 5.0)  # steps on the CPU
    assert any(not torch.equal(a, p) for a, p in zip(before, model.dvae.parameters(), strict=True))


def test_make_capturable_moves_the_step_counts_and_shares_the_rate():
    model, body, ids, data = parts("cpu")
    opt = torch.optim.Adam(model.dvae.parameters(), lr=1e-3, foreach=False)
    terms = prior_losses(model, model.dvae, data, body, ids, 0.5, 2.0, 4, 30.0, 0.1)
    clipped_step(opt, terms["loss"], model.dvae.parameters(), 5.0)
    lr = torch.tensor(7e-4)
    make_capturable(opt, lr)
    assert all(g["lr"] is lr and g["capturable"] for g in opt.param_groups)
    steps = [s["step"] for s in opt.state.values()]
    assert steps and all(s.dtype == torch.float32 and float(s) == 1.0 for s in steps)


# --- on a GPU ---------------------------------------------------------------------------------


def run_steps(graph: bool, n: int, seed: int = 0) -> tuple[list[float], PriorStep]:
    model, body, ids, data = parts("cuda", batch=32, T=12, seed=seed)
    opt = torch.optim.Adam(model.dvae.parameters(), lr=3e-3)
    step = PriorStep(
        model, model.dvae, body, ids, opt, model.dvae.parameters(), recon_w=30.0,
        velocity_w=0.1, body_w=2.0, body_stride=4, grad_clip=5.0, graph=graph,
    )  # fmt: skip
    losses = []
    for i in range(n):
        terms = step(data, 3e-3, min(1.0, i / 10), i + 1)
        losses.append(float(terms["loss"].detach()))
    return losses, step


@pytest.mark.skipif(not CUDA, reason="needs a GPU")
def test_graphed_step_trains_as_the_eager_one():
    eager, _ = run_steps(False, 120)
    graphed, step = run_steps(True, 120)
    assert step.graphed  # captured after the warm steps
    # the first steps are eager in both (same seed): equal; then both fall alike
    assert graphed[0] == pytest.approx(eager[0], rel=1e-4)
    assert graphed[-1] < 0.7 * graphed[0]
    assert graphed[-1] == pytest.approx(eager[-1], rel=0.2)


@pytest.mark.skipif(not CUDA, reason="needs a GPU")
def test_a_graphed_run_resumes_on_the_cpu(tmp_path):
    corpus = write_corpus(tmp_path / "data", n=3, T=40)
    run = tmp_path / "run"
    first = train_prior(tiny_config(corpus, epochs=2, batch_size=4, device="cuda"), run)
    assert first.steps > 0
    meta = json.loads((run / "last.json").read_text())
    assert all(isinstance(g["lr"], float) for g in meta["optimizer"]["param_groups"])
    cfg = json.loads((run / "config.json").read_text())
    cfg.update(epochs=3, device="cpu")
    (run / "config.json").write_text(json.dumps(cfg))
    from mdvae_cli.train.train_config import TrainConfig

    resumed = train_prior(TrainConfig.from_dict(cfg), run, resume=True)
    assert resumed.steps > first.steps


def test_validation_every_few_epochs_and_at_the_end(tmp_path):
    corpus = write_corpus(tmp_path / "data", n=3, T=40)
    run = tmp_path / "run"
    summary = train_prior(tiny_config(corpus, epochs=5, batch_size=4, val_every_epochs=2), run)
    logged = [json.loads(line)["epoch"] for line in (run / "log.jsonl").read_text().splitlines()]
    assert logged == [1, 3, 4]  # every second epoch, and the last
    assert json.loads((run / "last.json").read_text())["epoch"] == 4
    assert summary.epochs == 5
    # a budget that stops the run inside a skipped epoch still validates and saves there
    stopped = tmp_path / "stopped"
    train_prior(tiny_config(corpus, epochs=5, batch_size=4, val_every_epochs=4), stopped,
                max_steps=3)  # fmt: skip
    meta = json.loads((stopped / "last.json").read_text())
    assert (meta["epoch"], meta["step"]) == (1, 3)


# --- the lease's plan (weights_recipe/gpu_plan.py) ----------------------------------------------


def gpu_plan():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "weights_recipe" / "gpu_plan.py"
    spec = importlib.util.spec_from_file_location("gpu_plan", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_gpu_plan_shares_the_graphed_step_and_overlaps_eager_runs(tmp_path):
    plan = gpu_plan()
    rows = [{"mode": "eager", "batch": 1024, "s_per_step": 0.2},
            {"mode": "graph", "batch": 1024, "s_per_step": 0.05},
            {"mode": "graph", "batch": 64, "s_per_step": 0.01}]  # fmt: skip
    # graphed: the runs take turns on the GPU: 390 s / (4 runs x 0.05 s x 1.3) = 1,500 steps
    assert plan.plan(rows, 390.0, 4) == ("graph", 1500)
    # the graphed step failed its tests: eager runs overlap two-fold
    assert plan.plan(rows, 390.0, 4, eager=True) == ("eager", 750)
    # nothing measured: the fallback rate; never fewer than MIN_STEPS or more than MAX_STEPS
    assert plan.plan([], 10.0, 1) == ("eager", plan.MIN_STEPS)
    assert plan.plan(rows, 1e9, 1)[1] == plan.MAX_STEPS
    lines = tmp_path / "speed.jsonl"
    lines.write_text("a warning\n" + "\n".join(json.dumps(r) for r in rows) + "\n")
    assert plan.read_rows(lines) == rows
    assert plan.read_rows(tmp_path / "missing.jsonl") == []
