"""The denoiser and its sampler: a FiLM-conditioned 1-D U-Net over action chunks (Chi et al., Diffusion
Policy; DP3 conditions it the same way) and a deterministic DDIM schedule (Song et al., 2021). Training
runs them as written here; `fast_sampling` runs the same weights faster for sampling on a CPU."""

from __future__ import annotations

import math

import torch
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


class ConvBlock(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish on (B, C, T), length preserved."""

    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int):
        super().__init__(
            nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), nn.GroupNorm(groups, c_out), nn.Mish()
        )


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

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        """x (B, C_in, T), cond (B, cond_dim) -> (B, C_out, T)."""
        h = self.first(x)
        film = self.film(cond).unsqueeze(-1)
        h = h * film[:, : self.c_out] + film[:, self.c_out :] if self.use_scale else h + film
        return self.second(h) + self.skip(x)


class ConditionalUnet1d(nn.Module):
    """U-Net over the time axis of an action chunk, conditioned on (diffusion step, observation features),
    in the layout of LeRobot's diffusion policy (channels-first convolutions).

    `n_heads` > 1 gives one output projection per embodiment over a shared trunk (the naive co-training
    baseline); `head` picks each row's projection.
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
        # The FiLM blocks in the order `forward` runs them, listed once: sampling reads them every chunk.
        self.film_blocks = tuple(m for m in self.modules() if isinstance(m, FiLMResidualBlock))

    def forward(self, x: Tensor, t: Tensor, cond: Tensor, head: Tensor | None = None) -> Tensor:
        """x (B, T, A) noisy chunk, t (B,) steps, cond (B, C), head (B, A) each entry's head -> (B, T, A)."""
        cond = torch.cat([self.step_embedding(t), cond], dim=-1)
        h, skips = x.transpose(1, 2), []
        for first, second, down in self.down:
            h = second(first(h, cond), cond)
            skips.append(h)
            h = down(h)
        for block in self.mid:
            h = block(h, cond)
        for first, second, up in self.up:
            h = up(second(first(torch.cat([h, skips.pop()], dim=1), cond), cond))
        out = self.heads(self.final(h))
        if self.n_heads > 1:
            out = out.view(len(x), self.n_heads, self.action_dim, -1)
            out = out.gather(1, head.view(len(x), 1, self.action_dim, 1).expand(-1, 1, -1, out.shape[-1]))[
                :, 0
            ]
        return out.transpose(1, 2)


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
