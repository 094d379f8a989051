"""The denoiser and its sampler: a FiLM-conditioned 1-D U-Net over action chunks (Chi et al., Diffusion
Policy; DP3 conditions it the same way) and a deterministic DDIM schedule (Song et al., 2021)."""

from __future__ import annotations

import math
import warnings
from contextlib import contextmanager, nullcontext

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn


class SinusoidalEmbedding(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.dim = dim

    def forward(self, t: Tensor) -> Tensor:
        """(B,) timesteps -> (B, dim)."""
        half = self.dim // 2
        freq = torch.exp(-math.log(10000) * torch.arange(half, device=t.device) / (half - 1))
        angle = t.float()[:, None] * freq[None]
        return torch.cat([angle.sin(), angle.cos()], dim=-1)


def linear_weights(layer: nn.Conv1d | nn.ConvTranspose1d) -> tuple[Tensor, Tensor | None]:
    """A convolution as a linear layer: on the unfolded windows (conv) or on the input, whose per-tap
    products are then summed into overlapping windows (transposed conv)."""
    if isinstance(layer, nn.ConvTranspose1d):
        return layer.weight.flatten(1).T, None
    return layer.weight.flatten(1), layer.bias


def linear(x: Tensor, layer: nn.Conv1d | nn.ConvTranspose1d) -> Tensor:
    """`layer` as a linear layer on x, through its float16 weights while `float16_weights` has packed them."""
    packed = getattr(layer, "float16_packed", None)
    if packed is not None:
        return torch.ops.quantized.linear_dynamic_fp16(x, packed)
    return F.linear(x, *linear_weights(layer))


@contextmanager
def float16_weights(layers: list[nn.Conv1d | nn.ConvTranspose1d]):
    """Within: `conv` and `conv_transpose` multiply by float16 copies of the layers' weights and accumulate in
    float32 (fbgemm, CPU only). At batch 1 a U-Net pass on a CPU is bound by streaming its weights from
    memory, so half the bytes is a faster pass; products differ from float32 by about 2e-4 relative."""
    for layer in layers:
        weight, bias = linear_weights(layer)
        bias = None if bias is None else bias.detach()
        layer.float16_packed = torch.ops.quantized.linear_prepack_fp16(weight.detach().contiguous(), bias)
    try:
        yield
    finally:
        for layer in layers:
            del layer.float16_packed


def conv(x: Tensor, layer: nn.Conv1d) -> Tensor:
    """`layer` on time-major features (B, T, C): the unfolded windows times the flattened weights, one
    matmul. Same maths as `F.conv1d` on (B, C, T), several times faster on a CPU at batch 1, where
    `F.conv1d` takes an im2col path with the output laid out (C_out, T), a GEMM shape MKL runs poorly."""
    (k,), (stride,), (pad,) = layer.kernel_size, layer.stride, layer.padding
    if k > 1 or stride > 1:
        x = F.pad(x, (0, 0, pad, pad)).unfold(1, k, stride).flatten(2)
    return linear(x, layer)


def conv_transpose(x: Tensor, layer: nn.ConvTranspose1d) -> Tensor:
    """`layer` on time-major features (B, T, C): one matmul, then overlapping windows summed (col2im)."""
    (k,), (stride,), (pad,) = layer.kernel_size, layer.stride, layer.padding
    b, t, _ = x.shape
    length = (t - 1) * stride - 2 * pad + k
    cols = linear(x, layer).transpose(1, 2)
    out = F.fold(cols, (1, length), (1, k), padding=(0, pad), stride=(1, stride))
    return out.view(b, -1, length).transpose(1, 2) + layer.bias


class ConvBlock(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish on time-major features (B, T, C), length preserved."""

    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int):
        super().__init__(
            nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), nn.GroupNorm(groups, c_out), nn.Mish()
        )

    def forward(self, x: Tensor) -> Tensor:
        layer, norm, _ = self
        h = conv(x, layer).mT.unsqueeze(2)  # (B, C, 1, T), channels-last in memory: no copy for the norm
        return F.mish(F.group_norm(h, norm.num_groups, norm.weight, norm.bias, norm.eps)).squeeze(2).mT


class FiLMResidualBlock(nn.Module):
    """Two conv blocks; the conditioning vector scales and shifts the features between them (FiLM)."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int, kernel: int, groups: int, use_scale: bool):
        super().__init__()
        self.first, self.second = (
            ConvBlock(c_in, c_out, kernel, groups),
            ConvBlock(c_out, c_out, kernel, groups),
        )
        self.use_scale, self.c_out = use_scale, c_out
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, c_out * (2 if use_scale else 1)))
        self.skip = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: Tensor, film: Tensor) -> Tensor:
        """x (B, T, C_in), film (B, 1, C_out [* 2]): this block's FiLM output -> (B, T, C_out)."""
        h = self.first(x)
        h = torch.addcmul(film[..., self.c_out :], h, film[..., : self.c_out]) if self.use_scale else h + film
        return self.second(h) + (x if isinstance(self.skip, nn.Identity) else conv(x, self.skip))


class ConditionalUnet1d(nn.Module):
    """U-Net over the time axis of an action chunk, conditioned on (diffusion step, observation features).

    `n_heads` > 1 gives one output projection per embodiment over a shared trunk (the naive co-training
    baseline); `head` picks each row's projection. `cpu_float16_weights`: sampling on a CPU multiplies by
    float16 copies of the convolution weights (see `float16_weights`); training never does.
    """

    def __init__(
        self,
        action_dim: int,
        cond_dim: int,
        down_dims: tuple[int, ...],
        kernel: int,
        groups: int,
        step_embed_dim: int,
        use_scale: bool,
        n_heads: int = 1,
        cpu_float16_weights: bool = False,
    ):
        super().__init__()
        self.step_embedding = nn.Sequential(
            SinusoidalEmbedding(step_embed_dim),
            nn.Linear(step_embed_dim, step_embed_dim * 4),
            nn.Mish(),
            nn.Linear(step_embed_dim * 4, step_embed_dim),
        )
        cond_dim = cond_dim + step_embed_dim

        def block(c_in: int, c_out: int) -> FiLMResidualBlock:
            return FiLMResidualBlock(c_in, c_out, cond_dim, kernel, groups, use_scale)

        dims = [action_dim, *down_dims]
        self.down = nn.ModuleList()
        for i, (c_in, c_out) in enumerate(zip(dims[:-1], dims[1:], strict=True)):
            last = i == len(down_dims) - 1
            resample = nn.Identity() if last else nn.Conv1d(c_out, c_out, 3, stride=2, padding=1)
            self.down.append(nn.ModuleList([block(c_in, c_out), block(c_out, c_out), resample]))
        self.mid = nn.ModuleList([block(down_dims[-1], down_dims[-1]), block(down_dims[-1], down_dims[-1])])
        self.up = nn.ModuleList()
        for c_out, c_in in reversed(list(zip(down_dims[:-1], down_dims[1:], strict=True))):
            up = nn.ConvTranspose1d(c_out, c_out, 4, stride=2, padding=1)
            self.up.append(nn.ModuleList([block(c_in * 2, c_out), block(c_out, c_out), up]))
        self.final = ConvBlock(down_dims[0], down_dims[0], kernel, groups)
        self.n_heads, self.action_dim = n_heads, action_dim
        self.heads = nn.Conv1d(down_dims[0], action_dim * n_heads, 1)
        self.cpu_float16_weights = (
            cpu_float16_weights and "fbgemm" in torch.backends.quantized.supported_engines
        )
        self._traces: dict[tuple, torch.jit.ScriptModule] = {}
        self._traced_weights: tuple = ()

    def blocks(self) -> list[FiLMResidualBlock]:
        """The FiLM blocks in the order `denoise` runs them."""
        return [m for m in self.modules() if isinstance(m, FiLMResidualBlock)]

    def films(self, t: Tensor, cond: Tensor) -> list[Tensor]:
        """Each block's FiLM output (B, 1, F) for steps t (B,) and observation features cond (B, C): all that
        does not depend on the noisy sample, so sampling computes it once per chunk. The Mish every block's
        `film` starts with is applied once here, then each block's linear layer."""
        cond = F.mish(torch.cat([self.step_embedding(t), cond], dim=-1))
        return [block.film[1](cond).unsqueeze(1) for block in self.blocks()]

    def denoise(self, x: Tensor, films: list[Tensor], head: Tensor | None = None) -> Tensor:
        """x (B, T, A) noisy chunk, `films` from `films()`, head (B,) -> (B, T, A)."""
        films = iter(films)
        h, skips = x, []
        for first, second, down in self.down:
            h = second(first(h, next(films)), next(films))
            skips.append(h)
            h = h if isinstance(down, nn.Identity) else conv(h, down)
        for module in self.mid:
            h = module(h, next(films))
        for first, second, up in self.up:
            h = second(first(torch.cat([h, skips.pop()], dim=-1), next(films)), next(films))
            h = conv_transpose(h, up)
        out = conv(self.final(h), self.heads)
        if self.n_heads > 1:
            out = out.view(*out.shape[:2], self.n_heads, self.action_dim)  # each row's own head:
            index = head.view(-1, 1, 1, 1).expand(-1, out.shape[1], 1, self.action_dim)
            out = out.gather(2, index).squeeze(2)
        return out

    def forward(self, x: Tensor, t: Tensor, cond: Tensor, head: Tensor | None = None) -> Tensor:
        """x (B, T, A) noisy chunk, t (B,) steps, cond (B, C), head (B,) -> (B, T, A)."""
        return self.denoise(x, self.films(t, cond), head)

    def denoiser(self, timesteps: list[int], cond: Tensor, head: Tensor | None = None):
        """`denoise(x, i)` at the i-th of `timesteps` for observation features cond, for `Ddim.sample`:
        the FiLM inputs of all steps are computed up front in one batch. Outside training and autograd the
        steps run a frozen TorchScript trace of `denoise` (see `_traced`)."""
        b, n = len(cond), len(timesteps)
        t = torch.tensor(timesteps, device=cond.device).repeat_interleave(b)
        films = self.films(t, cond.repeat(n, 1))
        steps = list(zip(*(f.view(n, b, *f.shape[1:]).unbind() for f in films), strict=True))
        if self.training or torch.is_grad_enabled():
            return lambda x, i: self.denoise(x, steps[i], head)
        weights = tuple((p.data_ptr(), p._version) for p in self.parameters())
        if weights != self._traced_weights:  # an optimiser step or a load since the traces were made
            self._traces.clear()
            self._traced_weights = weights
        return lambda x, i: self._traced(x, steps[i], head)

    def _traced(self, x: Tensor, films: tuple[Tensor, ...], head: Tensor | None) -> Tensor:
        """`denoise` through a frozen trace made at the first call per input shape, device and dtype. A chunk
        is ten U-Net passes of hundreds of small ops at batch 1; run as one graph they skip Python's per-op
        dispatch, a third of a pass's time on a CPU, and freezing (weights as constants) takes off another
        sixth. `denoiser` drops the traces when the weights change. torch 2.11 marks `torch.jit.trace`
        deprecated in favour of `torch.compile`, which here costs about 50 s per process and a C++
        toolchain and ran no faster (3.9 vs 3.5 ms per pass), so the trace stays and its warnings are
        silenced."""
        inputs = (x, films) if head is None else (x, films, head)
        key = (x.shape, x.device, x.dtype, head is None)
        if key not in self._traces:
            float16 = self.cpu_float16_weights and x.device.type == "cpu" and x.dtype == torch.float32
            layers = [m for m in self.modules() if isinstance(m, (nn.Conv1d, nn.ConvTranspose1d))]
            with warnings.catch_warnings(), float16_weights(layers) if float16 else nullcontext():
                warnings.simplefilter("ignore", DeprecationWarning)
                warnings.simplefilter("ignore", torch.jit.TracerWarning)
                trace = torch.jit.trace(_Denoise(self), inputs, check_trace=False)
                self._traces[key] = torch.jit.freeze(trace.eval())
        return self._traces[key](*inputs)


class _Denoise(nn.Module):
    """`ConditionalUnet1d.denoise` as a module's forward, the form `torch.jit.trace` takes."""

    def __init__(self, unet: ConditionalUnet1d):
        super().__init__()
        self.unet = unet

    def forward(self, x: Tensor, films: tuple[Tensor, ...], head: Tensor | None = None) -> Tensor:
        return self.unet.denoise(x, list(films), head)


def alphas_cumprod(config_schedule: str, steps: int, beta_start: float, beta_end: float) -> Tensor:
    """alpha-bar_t for t = 0..steps-1: the squared-cosine schedule (Nichol & Dhariwal) or linear betas."""
    if config_schedule == "linear":
        betas = torch.linspace(beta_start, beta_end, steps, dtype=torch.float64)
    else:
        f = [math.cos((i / steps + 0.008) / 1.008 * math.pi / 2) ** 2 for i in range(steps + 1)]
        betas = torch.tensor([min(1 - f[i + 1] / f[i], 0.999) for i in range(steps)], dtype=torch.float64)
    return torch.cumprod(1 - betas, dim=0)


class Ddim(nn.Module):
    """Forward noising for training and the deterministic (eta = 0) DDIM reverse process: diffusers'
    `DDIMScheduler` ("leading" timesteps, alpha-bar 1 after the last step) stepped with
    `use_clipped_model_output=True`, as plain float arithmetic so that sampling a chunk costs no scheduler
    overhead."""

    def __init__(
        self,
        train_steps: int,
        inference_steps: int,
        schedule: str,
        beta_start: float,
        beta_end: float,
        prediction: str,
        clip: float | None,
    ):
        super().__init__()
        alpha_bar = alphas_cumprod(schedule, train_steps, beta_start, beta_end).float()
        self.register_buffer("alpha_bar", alpha_bar, persistent=False)
        self.alpha_bar_values = alpha_bar.tolist()  # for sampling: no tensor ops or device syncs per step
        self.train_steps, self.prediction, self.clip = train_steps, prediction, clip
        stride = train_steps // inference_steps  # diffusers' "leading" spacing
        self.timesteps = [i * stride for i in range(inference_steps)][::-1]

    def add_noise(self, x0: Tensor, noise: Tensor, t: Tensor) -> Tensor:
        a = self.alpha_bar[t].view(-1, *([1] * (x0.dim() - 1)))
        return a.sqrt() * x0 + (1 - a).sqrt() * noise

    def target(self, x0: Tensor, noise: Tensor) -> Tensor:
        return x0 if self.prediction == "sample" else noise

    def step(self, output: Tensor, t: int, x: Tensor, t_prev: int) -> Tensor:
        """One reverse step from t to t_prev (-1: the clean sample)."""
        a = self.alpha_bar_values[t]
        a_prev = self.alpha_bar_values[t_prev] if t_prev >= 0 else 1.0
        x0 = output if self.prediction == "sample" else (x - math.sqrt(1 - a) * output) / math.sqrt(a)
        if self.clip is not None:
            x0 = x0.clamp(-self.clip, self.clip)
        if self.prediction == "epsilon" and self.clip is None:
            eps = output
        else:
            eps = (x - math.sqrt(a) * x0) / math.sqrt(1 - a)
        return math.sqrt(a_prev) * x0 + math.sqrt(1 - a_prev) * eps

    def sample(self, denoise, noise: Tensor) -> Tensor:
        """Runs `denoise(x, i)` at the i-th inference timestep for each i in turn, starting from `noise`."""
        x = noise
        steps = self.timesteps
        for i, t in enumerate(steps):
            x = self.step(denoise(x, i), t, x, steps[i + 1] if i + 1 < len(steps) else -1)
        return x
