"""GaLR pretraining: mixed-hand batches of random reachable states, AdamW + cosine schedule, held-out
validation states, checkpoints with resume, scalars to `metrics.jsonl` (and wandb when asked), multi-GPU
through `accelerate` (the engine lerobot-train uses); one CPU works too."""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch
from accelerate import Accelerator
from tqdm import tqdm

from lerobot_opfa.galr import checkpoints
from lerobot_opfa.galr.data import HandBatch, make_batch, masked_rmse, sample_batch
from lerobot_opfa.galr.model import Galr, GalrConfig, hand_record
from lerobot_opfa.hands.registry import builtin_hands, load_hand, load_spec
from lerobot_opfa.process_group import hold_until_exit

logger = logging.getLogger(__name__)
CHECKPOINTS = "checkpoints"


@dataclass
class PretrainConfig:
    output_dir: Path
    hands: list[str] | None = None
    """Names or spec paths; None: the built-ins, or on `resume` the run's own."""
    steps: int = 3000
    batch_size: int = 44
    shares: str = "dof"
    """How a batch is shared out over the hands: `dof` (in proportion to their joints) or `even`."""
    lr: float = 1e-3
    min_lr: float = 1e-5
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    grad_clip: float = 1.0
    validate_every: int = 250
    save_every: int = 500
    validation_states: int = 64
    """Held-out states per hand, drawn from a generator no training batch uses."""
    max_minutes: float | None = None
    """Stop (saving a checkpoint) once this much wall time has passed."""
    init: str | None = None
    """Start from this trained GaLR (its architecture and hands) and add the `hands` it lacks: they get half
    of every batch, its own hands the other half, so the unified decoder learns them without forgetting."""
    anchor: float = 1.0
    """With `init`: weight of keeping its own hands' latents where `init` puts them (MSE over their
    variance), so that what the policies and datasets built on `init` read stays put."""
    seed: int = 0
    resume: bool = False
    wandb: bool = False
    push_to_hub: str | None = None
    model: GalrConfig = field(default_factory=GalrConfig)


def learning_rate(config: PretrainConfig, step: int, elapsed_s: float) -> float:
    """Linear warm-up, then cosine decay to `min_lr` at `steps` or at `max_minutes`, whichever comes first,
    so a time-budgeted run still ends annealed."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    progress = (step - config.warmup_steps) / max(1, config.steps - config.warmup_steps)
    if config.max_minutes is not None:
        progress = max(progress, elapsed_s / (60 * config.max_minutes))
    progress = min(1.0, progress)
    return config.min_lr + 0.5 * (config.lr - config.min_lr) * (1 + math.cos(math.pi * progress))


def validation_joints(galr: Galr, hands: list[str], n: int, seed: int) -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(10_000 + seed)
    return {name: galr.hand(name)[0].sample_joints(n, generator).cpu() for name in hands}


@torch.no_grad()
def validate(galr: Galr, joints: dict[str, torch.Tensor], chunk: int = 64) -> dict[str, float]:
    """RMSE in degrees (loss units: prismatic joints as PRISMATIC_SCALE x metres) per hand."""
    galr.eval()
    result = {}
    for name, q in joints.items():
        squared = []
        for part in q.split(chunk):
            batch = make_batch(galr, {name: part})
            _, target = batch.groups[0][0], batch.groups[0][2]
            squared.append((galr.decode_scaled(galr(*batch.encoder_inputs()), name) - target).square())
        result[name] = math.degrees(torch.cat(squared).mean().sqrt().item())
    galr.train()
    return result


def anchor_drift(anchor: Galr, batch: HandBatch, z: torch.Tensor, new_hands: tuple[str, ...]) -> torch.Tensor:
    """How far the latents of the hands `anchor` knows moved from its own, relative to their spread."""
    rows = torch.cat([torch.arange(len(z))[r] for name, r, _ in batch.groups if name not in new_hands])
    if len(rows) == 0:
        return z.new_zeros(())
    with torch.no_grad():
        reference = anchor(*(x[rows.to(x.device)] for x in batch.encoder_inputs()))
    return (z[rows.to(z.device)] - reference).square().mean() / reference.var().clamp(min=1e-8)


def extended(init: str, hands: list[str]) -> Galr:
    """The GaLR `init` with the hands it lacks (names or spec paths) added to its registry."""
    galr = checkpoints.load(init)
    if galr.config.decoder != "unified":
        raise ValueError(
            f"--init {init}: only a unified decoder can take new hands (it has '{galr.config.decoder}')"
        )
    known = set(galr.config.hand_names)
    records = [hand_record(load_hand(h)) for h in hands]
    new = [r for r in records if r["name"] not in known]
    if not new:
        raise ValueError(f"--init {init} already has every hand asked for ({', '.join(sorted(known))})")
    grown = Galr(replace(galr.config, hands=[*galr.config.hands, *new]))
    grown.load_state_dict(galr.state_dict())
    return grown


def _check_resumed_hands(config: PretrainConfig, trained: list[str]) -> None:
    """A resumed run keeps its hands: hands asked for that it does not train (or, starting afresh, hands
    it trains that were not asked for) are an error, not silently ignored."""
    asked = {load_spec(h).name for h in config.hands}
    missing = sorted(asked - set(trained))
    left_out = sorted(set(trained) - asked) if config.init is None else []
    if missing or left_out:
        raise ValueError(
            f"--resume continues a run on hands {trained}, but --hands asks for "
            f"{sorted(asked)}; leave --hands out to resume, or choose another --output-dir for other hands"
        )


def _latest_checkpoint(output_dir: Path) -> Path | None:
    found = sorted((output_dir / CHECKPOINTS).glob("step_*"))
    return found[-1] if found else None


def pretrain(config: PretrainConfig) -> Galr:
    output_dir = Path(config.output_dir)
    accelerator = Accelerator(log_with="wandb" if config.wandb else None)
    hold_until_exit()
    checkpoint = _latest_checkpoint(output_dir) if config.resume else None
    if config.resume and checkpoint is None:
        raise FileNotFoundError(f"--resume: no checkpoint under {output_dir / CHECKPOINTS}")
    if checkpoint is None and (output_dir / CHECKPOINTS).exists():
        raise FileExistsError(
            f"{output_dir} already holds a run; pass --resume or choose another --output-dir"
        )

    if checkpoint is not None:
        galr = Galr.from_pretrained(checkpoint)
        state = torch.load(checkpoint / "training_state.pt", weights_only=False)
        if config.hands is not None:
            _check_resumed_hands(config, galr.config.hand_names)
        config.hands = galr.config.hand_names
    elif config.init is not None:
        config.hands = config.hands or list(builtin_hands())
        galr, state = extended(config.init, config.hands), None
        config.model, config.hands = galr.config, galr.config.hand_names
    else:
        torch.manual_seed(config.seed)
        config.hands = config.hands or list(builtin_hands())
        config.model.hands = [hand_record(load_hand(name)) for name in config.hands]
        galr = Galr(config.model)
        state = None
    galr.to(accelerator.device)
    optimizer = torch.optim.AdamW(galr.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    galr, optimizer = accelerator.prepare(galr, optimizer)
    model: Galr = accelerator.unwrap_model(galr)
    generator = torch.Generator().manual_seed(config.seed + accelerator.process_index)
    step, elapsed = 0, 0.0
    if state is not None:
        optimizer.load_state_dict(state["optimizer"])
        generator.set_state(state["generator"])
        step, elapsed = state["step"], state["elapsed"]
        logger.info("resumed from %s at step %d", checkpoint, step)

    held_out = validation_joints(model, config.hands, config.validation_states, config.seed)
    anchor = (
        checkpoints.load(config.init).to(accelerator.device).requires_grad_(False) if config.init else None
    )
    new_hands = tuple(h for h in config.hands if h not in anchor.config.hand_names) if anchor else ()
    output_dir.mkdir(parents=True, exist_ok=True)
    (output_dir / "pretrain_config.json").write_text(json.dumps(asdict(config), indent=2, default=str))
    metrics = (output_dir / "metrics.jsonl").open("a")
    if config.wandb:
        accelerator.init_trackers("lerobot-opfa-galr", config=asdict(config))

    def log(values: dict) -> None:
        if accelerator.is_main_process:
            metrics.write(json.dumps({"step": step, "elapsed_s": round(elapsed, 1), **values}) + "\n")
            metrics.flush()
            accelerator.log(values, step=step)

    def save() -> None:
        accelerator.wait_for_everyone()
        if accelerator.is_main_process:
            target = output_dir / CHECKPOINTS / f"step_{step:07d}"
            model.save_pretrained(target)
            torch.save(
                {"optimizer": optimizer.state_dict(), "generator": generator.get_state(), "step": step,
                 "elapsed": elapsed},
                target / "training_state.pt",
            )  # fmt: skip

    progress = tqdm(total=config.steps, initial=step, desc="GaLR pretrain", unit="step",
                    disable=not accelerator.is_main_process)  # fmt: skip
    start = time.monotonic() - elapsed
    while step < config.steps:
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(config, step, time.monotonic() - start)
        batch = sample_batch(model, config.hands, config.batch_size, generator, config.shares, new_hands)
        z = galr(*batch.encoder_inputs())
        loss, per_hand = masked_rmse(model, batch, z)
        drift = anchor_drift(anchor, batch, z, new_hands) if anchor is not None else None
        if drift is not None:
            loss = loss + config.anchor * drift
        optimizer.zero_grad(set_to_none=True)
        accelerator.backward(loss)
        accelerator.clip_grad_norm_(galr.parameters(), config.grad_clip)
        optimizer.step()
        step, elapsed = step + 1, time.monotonic() - start
        progress.update()
        progress.set_postfix(loss=f"{loss.item():.4f}")
        log({"train/loss": loss.item(), "train/lr": optimizer.param_groups[0]["lr"]}
            | {f"train/rmse/{k}": v.item() for k, v in per_hand.items()}
            | ({"train/anchor_drift": drift.item()} if drift is not None else {}))  # fmt: skip
        out_of_time = config.max_minutes is not None and elapsed > 60 * config.max_minutes
        if step % config.validate_every == 0 or step == config.steps or out_of_time:
            rmse = validate(model, held_out)
            mean = sum(rmse.values()) / len(rmse)
            log({"val/rmse_deg_mean": mean} | {f"val/rmse_deg/{k}": v for k, v in rmse.items()})
            progress.set_postfix(loss=f"{loss.item():.4f}", val_deg=f"{mean:.2f}")
            progress.write(f"step {step}: val RMSE {mean:.2f} deg | "
                           + ", ".join(f"{k} {v:.1f}" for k, v in rmse.items()))  # fmt: skip
        if step % config.save_every == 0 or step == config.steps or out_of_time:
            save()
        if out_of_time:
            logger.info("stopping at step %d: --max-minutes %.1f reached", step, config.max_minutes)
            break
    progress.close()
    metrics.close()
    if accelerator.is_main_process:
        model.save_pretrained(output_dir)
        if config.push_to_hub:
            model.push_to_hub(config.push_to_hub)
    accelerator.end_training()
    return model
