"""Train the Motion-DVAE prior (paper Sec. 3.2): ELBO with KL warm-up + body-model regulariser."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch.nn.parallel import DistributedDataParallel

from mdvae_cli.body.formats import load_body_model
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError, diverged
from mdvae_cli.model.checkpoint import load_checkpoint, save_checkpoint
from mdvae_cli.model.config import require_int, require_number
from mdvae_cli.model.losses import kl_weight
from mdvae_cli.model.optim import warmup_cosine_lr
from mdvae_cli.model.prior_model import PriorModel, load_prior, model_tensors, widen_state
from mdvae_cli.model.state import VELOCITY_DIMS
from mdvae_cli.train.corpus import (
    WindowSet,
    check_val_splits,
    load_windows,
    no_training_files,
    no_validation,
    outside,
    select_files,
)
from mdvae_cli.train.distributed import (
    gather_strings,
    init_distributed,
    parameter_digest,
    shutdown_distributed,
)
from mdvae_cli.train.guards import (
    check_run_folder,
    checkpoint_to_resume,
    json_safe,
    pick_device,
    refuse_to_overwrite,
    weights_are_finite,
)
from mdvae_cli.train.prior_loss import prior_losses, spread_vertex_ids
from mdvae_cli.train.prior_step import PriorStep, graph_possible
from mdvae_cli.train.run_state import (
    optimizer_from_tensors,
    optimizer_to_tensors,
    restore_rng,
    rng_tensors,
    seed_streams,
    seeded_run,
)
from mdvae_cli.train.train_config import TRAINABLE, TrainConfig

REPORT_EVERY = 10  # steps between loss readings on a GPU


@torch.no_grad()
def evaluate(
    model: PriorModel,
    data: WindowSet,
    body: BodyModel,
    vertex_ids,
    cfg: TrainConfig,
    device,
    batch_size: int = 128,
) -> dict[str, float]:
    """Validation: the full-weight loss terms with a fixed noise seed."""
    model.eval()
    # the generators as they were afterwards (the GPU's too: steps' noise goes on as it was)
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        seed_streams(1234, device)
        totals, n = _evaluate_batches(model, data, body, vertex_ids, cfg, device, batch_size)
    model.train()
    return {k: v / n for k, v in totals.items()}


def _evaluate_batches(model, data, body, vertex_ids, cfg, device, batch_size):
    """Each term summed over the validation batches, weighted by their windows, and the
    number of windows.  -> (totals, n)"""
    totals: dict[str, float] = {}
    n = 0
    for i in range(0, len(data), batch_size):
        batch = data.subset(torch.arange(i, min(i + batch_size, len(data))))
        batch = WindowSet(*(t.to(device) for t in (batch.x0, batch.x, batch.betas)))
        terms = prior_losses(
            model,
            model.dvae,
            batch,
            body,
            vertex_ids,
            1.0,
            cfg.body_weight,
            1,
            cfg.recon_weight,
            cfg.velocity_weight,
        )
        for k, v in terms.items():
            totals[k] = totals.get(k, 0.0) + float(v) * len(batch)
        n += len(batch)
    return totals, n


@dataclass
class TrainSummary:
    run_dir: str
    epochs: int
    steps: int
    best_val_loss: float
    seconds: float
    train_windows: int
    val_windows: int
    rank_digests: list[str]
    #: whether the step ran as a CUDA graph, and why not where its capture failed
    graphed: bool = False
    graph_failure: str | None = None
    #: whether a stop asked for (``stop_requested``) ended the run
    interrupted: bool = False


def _save(run_dir: Path, name: str, model, opt, meta: dict, device=None) -> None:
    """A checkpoint; with ``opt`` (the one a run resumes from) also Adam's state and the
    random generators' states, so that a resumed run draws what the run would have drawn."""
    tensors = model_tensors(model)
    if opt is not None:
        t, groups = optimizer_to_tensors(opt)
        tensors.update(t)
        tensors.update(rng_tensors(device))
        meta = {**meta, "optimizer": groups}
    save_checkpoint(run_dir / f"{name}.npz", tensors, json_safe(meta))


def trainable_parameters(model: PriorModel, which: str) -> list[torch.nn.Parameter]:
    """The parameters a run trains: all networks, or one of them with the other two frozen
    ("encoder": sampling unchanged; "prior": the decoder and the posterior unchanged, the
    prior network alone fitted to the encoder's posteriors by the KL term)."""
    if which not in TRAINABLE:
        raise InputError(f"train_only must be one of {', '.join(TRAINABLE)}, got {which!r}")
    if which == "all":
        return list(model.dvae.parameters())
    trained = getattr(model.dvae, which)
    for module in (model.dvae.prior, model.dvae.decoder, model.dvae.encoder):
        module.requires_grad_(module is trained)
    return list(trained.parameters())


def init_from_prior(model: PriorModel, path: Path) -> None:
    """Start from a trained prior (fine-tuning): its weights *and* its normaliser."""
    source, _ = load_prior(path, keep_rng=False)  # the seeded run draws as it always did
    sizes = {"latent_dim": "--latent-dim", "hidden_dim": "--hidden-dim", "mlp_dim": None}
    other = [n for n in sizes if getattr(source.cfg, n) != getattr(model.cfg, n)]
    if other:  # widen_state fits extra inputs only: the widths must be the same
        give = " ".join(f"{sizes[n]} {getattr(source.cfg, n)}" for n in other if sizes[n])
        raise InputError(
            f"--init-from {path}: its networks have "
            + ", ".join(f"{n} {getattr(source.cfg, n)}" for n in other)
            + f", this run's {', '.join(str(getattr(model.cfg, n)) for n in other)}: give "
            + (f"{give}, or " if give and "mlp_dim" not in other else "")
            + "--config with the config.json of the run it comes from"
        )
    try:
        model.load_state_dict(widen_state(source.state_dict(), model.state_dict()))
    except ValueError as exc:
        raise InputError(f"--init-from {path}: {exc}") from None


def stop_now(
    step: int, max_steps: int | None, deadline: float | None, dist, device,
    asked: bool | None = None,
) -> bool:  # fmt: skip
    """Whether a run stops after ``step``: its step budget, its wall-clock ``deadline``, or a
    stop ``asked`` for (None: none can be; under DDP rank 0 decides for all, so that every
    rank stops at the same step)."""
    if max_steps is not None and step >= max_steps:
        return True
    if deadline is None and asked is None:
        return False
    late = torch.tensor([asked or (deadline is not None and time.time() >= deadline)],
                        dtype=torch.int32)  # fmt: skip
    if dist.enabled:
        late = late.to(device)
        torch.distributed.broadcast(late, 0)
        late = late.cpu()
    return bool(late.item())


@seeded_run  # with cfg.seed; the caller's random streams (CPU, GPUs) as they were
def train_prior(
    cfg: TrainConfig,
    run_dir: Path,
    resume: bool = False,
    progress: Callable[[dict], None] | None = None,
    max_steps: int | None = None,
    max_minutes: float | None = None,
    stop_requested: Callable[[], bool] | None = None,
) -> TrainSummary:
    """Train (or resume) a prior into ``run_dir``; works alone or under torchrun (DDP).

    ``progress`` receives a dict after every step (epoch, step, steps_per_epoch, loss terms)
    and after every epoch (with ``val``). ``max_steps`` (>= 1) stops early (tests);
    ``max_minutes`` (> 0) stops after the first step that ends past that much wall time since
    the start (a GPU lent for minutes): either way the run ends with its validation and a
    checkpoint that ``resume`` continues exactly where it stopped. ``stop_requested`` (asked
    after every step; a Ctrl-C or SIGTERM the caller caught) stops the run the same way, but
    at once: its checkpoint is saved without a validation (``TrainSummary.interrupted``). ``cfg``
    is validated here (fields may have changed since it was made). A loss or weights that
    stop being finite end the run with InputError before anything of them is saved.
    """
    cfg.validate()
    if max_steps is not None:
        require_int("--max-steps", max_steps, 1)
    if max_minutes is not None:
        require_number("--max-minutes", max_minutes, 0.0, open_low=True)
    start = time.time()
    deadline = None if max_minutes is None else start + 60.0 * max_minutes
    run_dir = Path(run_dir)
    if not resume:
        refuse_to_overwrite(run_dir, "train-prior")
    check_run_folder(run_dir)
    device = pick_device(cfg.device)
    dist = init_distributed(device)
    if device.type == "cuda" and dist.enabled:
        device = torch.device("cuda", dist.local_rank)
    try:
        body = BodyModel(load_body_model(cfg.body_model)).to(device)
        vertex_ids = spread_vertex_ids(body.v_template.shape[0], cfg.body_vertices).to(device)
        split = Path(cfg.split_file) if cfg.split_file else None
        data = [Path(p) for p in cfg.data]
        # a run folder inside a data folder: its checkpoints are not motion
        train_files = outside(select_files(data, split, "train"), run_dir)
        if split is None and list(cfg.val_splits) != ["val"]:
            raise InputError("--val-split other than val needs --split (a split file)")
        if split is not None:
            check_val_splits(cfg.val_splits, split)
        val_files = [f for name in cfg.val_splits for f in select_files(data, split, name)]
        val_files = outside(list(dict.fromkeys(val_files)), run_dir)
        if not train_files:
            raise InputError(no_training_files(data, split, val_files))
        cpu_body = BodyModel(body.data)
        train = load_windows(
            train_files, cpu_body, cfg.window, cfg.stride, mirror=cfg.mirror_augment,
            speeds=tuple(cfg.speeds), fraction=cfg.data_fraction, fraction_seed=cfg.seed,
        )  # fmt: skip
        val = None
        if val_files:  # files too short for one window leave the run without validation
            val = load_windows(val_files, cpu_body, cfg.window, cfg.window, required=False)
        if val is None and progress is not None and dist.is_main:
            progress({"note": no_validation(len(val_files), cfg.window)})
        if val is not None and len(val) > cfg.max_val_windows:
            pick = torch.linspace(0, len(val) - 1, cfg.max_val_windows).long()
            val = val.subset(pick)

        model = PriorModel(cfg.model)
        model.normalizer.fit(train.x0, train.x)
        if device.type == "cuda":  # the windows stay on the device: no copy per step
            train = WindowSet(*(t.to(device) for t in (train.x0, train.x, train.betas)))
        model.normalizer.scale_std(VELOCITY_DIMS, cfg.velocity_std_scale)
        if cfg.init_from and not resume:
            init_from_prior(model, Path(cfg.init_from))
        model.to(device)
        opt = torch.optim.Adam(trainable_parameters(model, cfg.train_only), lr=cfg.lr)
        steps_per_epoch = max(1, len(train) // (cfg.batch_size * dist.world_size))
        total_steps = steps_per_epoch * cfg.epochs
        first_epoch, step, best, skip = 0, 0, math.inf, 0
        if resume:
            last = checkpoint_to_resume(run_dir, "last.npz")
            tensors, meta = load_checkpoint(last)
            if not all(k in meta for k in ("optimizer", "epoch", "step")):
                raise InputError(
                    f"{last} cannot be resumed: {last.with_suffix('.json').name} lacks the "
                    "optimizer state and step a run saves there; start a new run instead"
                )
            model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model/")})
            opt.load_state_dict(optimizer_from_tensors(tensors, meta["optimizer"]))
            first_epoch, step = meta["epoch"] + 1, meta["step"]
            if cfg.epochs < first_epoch:  # the run would record a schedule it went past
                raise InputError(
                    f"--epochs {cfg.epochs}: the run in {run_dir} has already reached epoch "
                    f"{first_epoch}; give at least {first_epoch} to resume it"
                )
            if meta.get("epoch_steps", steps_per_epoch) < steps_per_epoch:  # --max-steps
                # stopped the run inside that epoch: the resumed run takes the rest of it
                first_epoch, skip = meta["epoch"], meta["epoch_steps"]
            best = meta["best_val_loss"] if meta.get("best_val_loss") is not None else math.inf
            restore_rng(tensors, device)
        if dist.is_main:
            run_dir.mkdir(parents=True, exist_ok=True)
            # a summary of an earlier, finished run no longer describes this folder
            (run_dir / "summary.json").unlink(missing_ok=True)
            (run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
        forward = DistributedDataParallel(model.dvae) if dist.enabled else model.dvae
        take_step = PriorStep(
            model, forward, body, vertex_ids, opt, model.dvae.parameters(),
            recon_w=cfg.recon_weight, velocity_w=cfg.velocity_weight, body_w=cfg.body_weight,
            body_stride=cfg.body_frame_stride, grad_clip=cfg.grad_clip, dist=dist,
            graph=cfg.cuda_graph
            and graph_possible(device, dist.enabled, cfg.window, cfg.body_frame_stride),
        )  # fmt: skip
        meta_base = {
            "model_config": cfg.model.to_dict(),
            "train_config": cfg.to_dict(),
            "body_model": body.data.name or body.data.kind,
        }
        model.train()
        epoch, stopped, interrupted = first_epoch - 1, False, False
        for epoch in range(first_epoch, cfg.epochs):
            # the epoch's order (mod 2^64: any seed fits; the same numbers as ever below ~1e16)
            gen = torch.Generator().manual_seed((cfg.seed * 1000 + epoch) % 2**64)
            perm = torch.randperm(len(train), generator=gen)
            mine = perm[dist.rank :: dist.world_size].to(train.x.device)
            taken = steps_per_epoch
            for i in range(skip if epoch == first_epoch else 0, steps_per_epoch):
                idx = mine[i * cfg.batch_size : (i + 1) * cfg.batch_size]
                b = train.subset(idx)
                batch = WindowSet(b.x0.to(device), b.x.to(device), b.betas.to(device))
                lr = warmup_cosine_lr(step, total_steps, cfg.lr, cfg.lr_final, cfg.lr_warmup_steps)
                kl_w = cfg.kl_max * kl_weight(step, cfg.kl_warmup_steps)
                terms = take_step(batch, lr, kl_w, step + 1)
                step += 1
                if progress is not None and dist.is_main:
                    # the loss terms as numbers every REPORT_EVERY steps: on a GPU each
                    # reading waits for the device
                    report = step % REPORT_EVERY == 0 or device.type == "cpu"
                    progress(
                        {
                            "epoch": epoch,
                            "step": step,
                            "steps_per_epoch": steps_per_epoch,
                            "epochs": cfg.epochs,
                            "kl_w": kl_w,
                            **({k: v.item() for k, v in terms.items()} if report else {}),
                        }
                    )
                asked = None if stop_requested is None else bool(stop_requested())
                if stop_now(step, max_steps, deadline, dist, device, asked):
                    taken, stopped, interrupted = i + 1, True, bool(asked)
                    break
            if not weights_are_finite(model):  # every rank holds the same weights
                raise diverged("training", step, "weights not finite")
            last_epoch = epoch == cfg.epochs - 1
            if (epoch + 1) % cfg.val_every_epochs and not (stopped or last_epoch):
                continue  # validation and checkpoints every val_every_epochs epochs
            if dist.is_main:
                checked = val and not interrupted  # a stop asked for: no time for validation
                val_terms = evaluate(model, val, body, vertex_ids, cfg, device) if checked else {}
                val_loss = val_terms.get("loss", terms["loss"].item())
                if interrupted:
                    val_loss = math.inf  # nothing measured: not a best
                meta = {
                    **meta_base,
                    "epoch": epoch,
                    "step": step,
                    "val": val_terms,
                    "best_val_loss": val_loss if val_loss < best else best,
                    # batches of this epoch taken, where the run stopped inside it
                    **({"epoch_steps": taken} if taken < steps_per_epoch else {}),
                }
                if val_loss < best:
                    best = val_loss
                    _save(run_dir, "best", model, None, meta)
                _save(run_dir, "last", model, opt, meta, device)
                with open(run_dir / "log.jsonl", "a") as fh:
                    record = {
                        "epoch": epoch,
                        "step": step,
                        "val": val_terms,
                        "train_loss": terms["loss"].item(),
                        "seconds": time.time() - start,
                        **({"interrupted": True} if interrupted else {}),
                    }
                    fh.write(json.dumps(json_safe(record)) + "\n")
                if progress is not None and not interrupted:
                    progress({"epoch": epoch, "step": step, "val": val_terms, "epoch_end": True,
                              "train_loss": terms["loss"].item()})  # fmt: skip
            if stopped:  # by --max-steps or --max-minutes
                break
        digests = gather_strings(dist, parameter_digest(model))
        summary = TrainSummary(
            str(run_dir),
            epoch + 1,
            step,
            best,
            time.time() - start,
            len(train),
            len(val) if val else 0,
            digests,
            take_step.graphed,
            take_step.failure,
            interrupted,
        )
        if dist.is_main:
            text = json.dumps(json_safe(asdict(summary)), indent=2, allow_nan=False)
            (run_dir / "summary.json").write_text(text + "\n")
        return summary
    finally:
        shutdown_distributed(dist)
