"""One training step of the prior (loss, backward, clipping, Adam), as ``train_prior`` and
``benchmarks/train_speed.py`` take it.

On a CPU (and under DDP) the step runs as written. On a GPU it is bound by kernel launches,
not arithmetic: the encoder's 60 recurrent steps are a few thousand small kernels forward and
backward, and a batch of 1024 windows costs about what 64 do (issue 30). There the step is
captured once as a CUDA graph and replayed: the batch, the learning rate, the KL weight and the
body term's frames are copied into fixed buffers the graph reads, Adam runs ``capturable``
(its step counts and rate on the device), and nothing waits for the device inside the step.
The first :data:`WARM_STEPS` steps run eagerly on a side stream (they are real steps) so that
Adam's state and the libraries' workspaces exist before the capture.
"""

from __future__ import annotations

import traceback
from collections.abc import Iterable
from pathlib import Path

import torch

from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.errors import InputError, diverged
from mdvae_cli.model.optim import clipped_step, set_lr
from mdvae_cli.model.prior_model import PriorModel
from mdvae_cli.model.state import VELOCITY_DIMS
from mdvae_cli.train.corpus import WindowSet
from mdvae_cli.train.guards import loss_is_finite
from mdvae_cli.train.prior_loss import prior_losses

#: eager steps before the capture
WARM_STEPS = 3
#: steps between finiteness checks of a graphed step's loss (each one waits for the device)
CHECK_EVERY = 10


def graph_possible(device: torch.device, distributed: bool, window: int, stride: int) -> bool:
    """Whether the step can be captured: a GPU, one process, and a body-term stride that takes
    the same number of frames at every phase."""
    return device.type == "cuda" and not distributed and window % stride == 0


def failure_note(exc: BaseException) -> str:
    """One line: the error, and the innermost line of this package that raised it."""
    ours = [f for f in traceback.extract_tb(exc.__traceback__) if "mdvae_cli" in f.filename]
    where = f" (at {Path(ours[-1].filename).name}:{ours[-1].lineno})" if ours else ""
    return f"{type(exc).__name__}: {exc}".splitlines()[0] + where


def without_cudnn():
    """The graphed step runs torch's own GRU kernels: cuDNN's recurrent layers may copy their
    sequence lengths from the host on each call, which a CUDA graph cannot hold (a precaution:
    not tried inside the graph; its speed there is the next thing to measure)."""
    return torch.backends.cudnn.flags(enabled=False)


def make_capturable(opt: torch.optim.Optimizer, lr: torch.Tensor) -> None:
    """Turn an Adam (fresh or resumed) into one a CUDA graph can hold: ``capturable``, its
    rate the device tensor ``lr`` (0-d), its step counts on the parameters' device."""
    for group in opt.param_groups:
        group["capturable"] = True
        group["lr"] = lr
        for p in group["params"]:
            state = opt.state.get(p)
            if state and "step" in state:
                state["step"] = torch.as_tensor(state["step"], dtype=torch.float32).to(p.device)


class PriorStep:
    """Call with a batch, the learning rate, the KL weight and the 1-based step number: takes
    one step and returns the loss terms (device tensors; a graphed step's are its fixed
    outputs, overwritten by the next call). A loss that is not finite raises InputError
    (eagerly before the weights change; graphed, at the next check, before any save). Where
    the capture fails, the step runs eagerly from then on and :attr:`failure` says why."""

    def __init__(
        self,
        model: PriorModel,
        forward,
        body: BodyModel,
        vertex_ids: torch.Tensor,
        opt: torch.optim.Optimizer,
        params: Iterable[torch.nn.Parameter],
        *,
        recon_w: float,
        velocity_w: float,
        body_w: float,
        body_stride: int,
        grad_clip: float,
        graph: bool = False,
        dist=None,
    ):
        self.model, self.forward, self.body, self.vertex_ids = model, forward, body, vertex_ids
        self.opt, self.params = opt, list(params)
        self.recon_w, self.velocity_w, self.body_w = recon_w, velocity_w, body_w
        self.body_stride, self.grad_clip, self.dist = body_stride, grad_clip, dist
        self.graph_wanted = graph
        self.graph: torch.cuda.CUDAGraph | None = None
        self.calls = 0
        # the graph's fixed inputs (made at its first call): the batch, the rate, the KL weight,
        # the body term's frames (from ``frame_base`` at the step's phase), the velocity columns
        self.static: WindowSet | None = None
        self.lr = self.kl_w = self.frame_base = self.frames = self.velocity_dims = None
        self.terms: dict[str, torch.Tensor] = {}
        #: why the capture failed, where it did (the step then runs as written)
        self.failure: str | None = None

    @property
    def graphed(self) -> bool:
        return self.graph is not None

    def __call__(self, batch: WindowSet, lr: float, kl_w: float, step: int):
        if not self.graph_wanted:
            return self._eager(batch, lr, kl_w, step)
        return self._graphed(batch, lr, kl_w, step)

    def _eager(self, batch, lr, kl_w, step):
        set_lr(self.opt, lr)
        terms = prior_losses(
            self.model, self.forward, batch, self.body, self.vertex_ids, kl_w, self.body_w,
            self.body_stride, self.recon_w, self.velocity_w,
        )  # fmt: skip
        if not loss_is_finite(terms["loss"], self.dist):  # the weights are still good
            raise diverged("training", step, f"loss {terms['loss'].item():g}")
        clipped_step(self.opt, terms["loss"], self.params, self.grad_clip)
        return terms

    # --- the graphed step ------------------------------------------------------------------
    def _prepare(self, batch: WindowSet) -> None:
        device = batch.x.device
        self.static = WindowSet(batch.x0.clone(), batch.x.clone(), batch.betas.clone())
        self.lr = torch.zeros((), device=device)
        self.kl_w = torch.zeros((), device=device)
        T = batch.x.shape[1]
        self.frame_base = torch.arange(0, T, self.body_stride, device=device)
        self.frames = self.frame_base.clone()
        self.velocity_dims = torch.as_tensor(VELOCITY_DIMS, device=device)
        make_capturable(self.opt, self.lr)

    def _losses(self) -> dict[str, torch.Tensor]:
        return prior_losses(
            self.model, self.forward, self.static, self.body, self.vertex_ids, self.kl_w,
            self.body_w, self.body_stride, self.recon_w, self.velocity_w,
            frames=self.frames, velocity_dims=self.velocity_dims,
        )  # fmt: skip

    def _update(self) -> dict[str, torch.Tensor]:
        terms = self._losses()
        terms["loss"].backward()
        torch.nn.utils.clip_grad_norm_(self.params, self.grad_clip)
        self.opt.step()
        return terms

    def _graphed(self, batch, lr, kl_w, step):
        if batch.x.shape[1] % self.body_stride:
            raise InputError("a graphed step needs a window that the body stride divides")
        if self.static is None:
            self._prepare(batch)
        # the phase from the CPU generator, as the eager step draws it
        phase = int(torch.randint(self.body_stride, (1,)))
        for name in ("x0", "x", "betas"):
            getattr(self.static, name).copy_(getattr(batch, name))
        self.lr.fill_(lr)
        self.kl_w.fill_(kl_w)
        torch.add(self.frame_base, phase, out=self.frames)
        self.calls += 1
        if self.graph is None and self.calls <= WARM_STEPS:
            side = torch.cuda.Stream()
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side), without_cudnn():
                self.opt.zero_grad(set_to_none=True)
                terms = self._update()
            torch.cuda.current_stream().wait_stream(side)
            self._check(terms, step, every=1)
            # no autograd graph kept alive: its gradient nodes would run on this side stream
            # inside the capture
            return {k: v.detach() for k, v in terms.items()}
        if self.graph is None:
            try:
                self._capture()
            except RuntimeError as exc:  # a library that cannot be captured: run as written
                self.failure = failure_note(exc)
                self.graph_wanted = False
                torch.cuda.synchronize()
                return self._eager(batch, lr, kl_w, step)
        self.graph.replay()
        self._check(self.terms, step, every=CHECK_EVERY)
        return self.terms

    def _capture(self) -> None:
        torch.cuda.synchronize()
        self.opt.zero_grad(set_to_none=True)
        graph = torch.cuda.CUDAGraph()
        with without_cudnn(), torch.cuda.graph(graph):
            self.terms = self._update()
        self.terms = {k: v.detach() for k, v in self.terms.items()}
        self.graph = graph

    def _check(self, terms, step: int, every: int) -> None:
        if step % every == 0 and not loss_is_finite(terms["loss"]):
            raise diverged("training", step, f"loss {terms['loss'].item():g}")
