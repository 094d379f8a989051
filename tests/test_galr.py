"""GaLR on tiny configs: shapes, kernel points, batch independence, masked loss, checkpoints, registry
checks, resume, and the CLI end to end."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from lerobot_opfa.galr.data import hand_counts, make_batch, masked_rmse, sample_batch
from lerobot_opfa.galr.evaluate import evaluate
from lerobot_opfa.galr.kpconv import kernel_points
from lerobot_opfa.galr.model import Galr, GalrConfig, hand_record, joint_scale
from lerobot_opfa.galr.train import PretrainConfig, pretrain
from lerobot_opfa.hands import HandModel, load_hand
from lerobot_opfa.hands.registry import hand_models_dir

HANDS = ["umi", "leap", "inspire"]
TINY = dict(
    latent_dim=16, n_points=128, n_level1=48, n_superpoints=20, widths=(16, 32, 64), transformer_dim=32,
    transformer_heads=2, transformer_layers=1, structure_dim=8, decoder_hidden=32,
    neighbor_limits=(12, 8, 12, 8),
)  # fmt: skip
TINY_ARGS = [f"{k}={','.join(map(str, v)) if isinstance(v, tuple) else v}" for k, v in TINY.items()]


def tiny_galr(hands=HANDS, **overrides) -> Galr:
    torch.manual_seed(0)
    return Galr(GalrConfig(**{**TINY, **overrides}, hands=[hand_record(load_hand(h)) for h in hands])).eval()


def _joints(hand: str, n: int, seed: int = 0) -> torch.Tensor:
    return load_hand(hand).sample_joints(n, torch.Generator().manual_seed(seed))


@pytest.mark.parametrize(
    "overrides",
    [{}, {"semantic_embedding": "table"}, {"semantic_embedding": "none"}, {"semantic_target": "attention"},
     {"encoder": "pointnet"}, {"decoder": "per_embodiment"}],
)  # fmt: skip
def test_shapes_for_every_ablation(overrides):
    galr = tiny_galr(**overrides)
    for hand in HANDS:
        z = galr.encode_joints(hand, _joints(hand, 3))
        assert z.shape == (3, 16) and torch.isfinite(z).all()
        q, model = galr.decode(z, hand), load_hand(hand)
        raw = galr.decode_scaled(z, hand) / joint_scale(model)  # before the clamp to the joint limits
        assert q.shape == raw.shape == (3, model.dof)
        assert torch.equal(q, torch.maximum(torch.minimum(raw, model.upper), model.lower))


@pytest.mark.parametrize("target", ["features", "attention"])
def test_semantic_labels_reach_the_superpoint_values_only_as_features(target):
    """Two superpoints with the same geometry and attention but different finger labels: with `features`
    their outputs differ, so pooling keeps which finger moved; with `attention` they stay the same."""
    transformer = tiny_galr(semantic_target=target).encoder.transformer
    points = torch.tensor([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.02]]])
    width = TINY["transformer_dim"]
    labels = torch.tensor([[[2, 2], [3, 2]]])  # index and middle fingertip
    out = transformer(torch.ones(1, 2, width), points, labels)
    assert out.shape == (1, 2, width)
    if target == "features":
        assert (out[0, 0] - out[0, 1]).abs().max() > 1e-3
    else:
        assert torch.allclose(out[0, 0], out[0, 1])


def test_checkpoint_config_from_before_semantic_target_and_stem_neighbors_loads_as_it_was(tmp_path):
    galr = tiny_galr(semantic_target="attention", stem_neighbors="radius")
    galr.save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    del config["semantic_target"], config["stem_neighbors"]  # as written before the fields existed
    (tmp_path / "config.json").write_text(json.dumps(config))
    loaded = Galr.from_pretrained(tmp_path).eval()
    assert (loaded.config.semantic_target, loaded.config.stem_neighbors) == ("attention", "radius")
    q = _joints("leap", 2)
    assert torch.equal(galr.encode_joints("leap", q), loaded.encode_joints("leap", q))
    with pytest.raises(ValueError, match="semantic_target must be"):
        tiny_galr(semantic_target="values")
    with pytest.raises(ValueError, match="stem_neighbors must be"):
        tiny_galr(stem_neighbors="knn")


def test_a_galr_saved_by_an_earlier_version_encodes_as_it_did():
    """A tiny KPConv GaLR written by `tests/data/galr_v1/make.py` before the encoder's speed work (its
    stem searched, its config without `stem_neighbors`) gives the latents it gave then."""
    from safetensors.torch import load_file

    folder = Path(__file__).parent / "data" / "galr_v1"
    expected = load_file(folder / "latents.safetensors")
    galr = Galr.from_pretrained(folder / "galr").eval()
    assert galr.config.stem_neighbors == "radius"
    for hand in HANDS:
        with torch.no_grad():
            latents = galr.encode_joints(hand, expected[f"{hand}/joints"])
        assert torch.allclose(latents, expected[f"{hand}/latents"], atol=1e-5), hand


@pytest.mark.parametrize("hand", HANDS)
def test_link_neighbourhoods_found_once_are_the_radius_neighbourhoods_on_the_link_in_every_pose(hand):
    """The stem's `link` neighbourhoods, found once in the links' frames, are in any pose exactly the dense
    points within the radius on the query's own link."""
    galr = tiny_galr()
    model, index = galr.hand(hand)
    c = galr.config
    radius, limit = c.radius_factor * c.grid, c.neighbor_limits[0]
    samples = model.surface_samples(c.n_points, c.sample_seed)
    points = model.point_cloud(_joints(hand, 3, seed=2), c.n_points, c.sample_seed).points
    checked = 0
    for cloud in points:
        distances = torch.cdist(cloud[index.level1], cloud)
        same_link = samples.link_index[index.level1].unsqueeze(1) == samples.link_index.unsqueeze(0)
        for row, found in enumerate(index.stem):
            within = ((distances[row] <= radius) & same_link[row]).nonzero().flatten()
            found = found[found < c.n_points]
            if len(within) <= limit:  # else the nearest `limit` of them
                assert set(found.tolist()) == set(within.tolist())
                checked += 1
            else:
                assert len(found) == limit and set(found.tolist()) <= set(within.tolist())
    assert checked > 0.5 * len(points) * len(index.stem)


def test_kernel_points_deterministic_and_saved(tmp_path):
    first, second = kernel_points(15), kernel_points(15)
    assert torch.equal(first, second) and first.shape == (15, 3)
    assert torch.equal(first[0], torch.zeros(3))
    assert torch.allclose(first[1:].norm(dim=1), torch.full((14,), 0.66))
    galr = tiny_galr()
    galr.save_pretrained(tmp_path)
    state = Galr.from_pretrained(tmp_path).state_dict()
    assert torch.equal(state["encoder.stem.kernel"], galr.encoder.stem.kernel)
    assert "encoder.stem.kernel" in galr.state_dict()


def test_latent_of_a_hand_does_not_depend_on_its_batch_mates():
    galr = tiny_galr()
    alone = galr.encode_joints("leap", _joints("leap", 1, seed=5))
    batch = make_batch(
        galr, {"leap": _joints("leap", 1, seed=5), "umi": _joints("umi", 4), "inspire": _joints("inspire", 3)}
    )
    together = galr(*batch.encoder_inputs())[:1]
    assert torch.allclose(alone, together, atol=1e-5)
    batch = make_batch(galr, {"leap": torch.cat([_joints("leap", 1, seed=5), _joints("leap", 7, seed=6)])})
    assert torch.allclose(alone, galr(*batch.encoder_inputs())[:1], atol=1e-5)


def test_batch_shares_follow_joint_counts():
    dofs, generator = [1, 6, 18], torch.Generator().manual_seed(0)
    draws = torch.stack([hand_counts(dofs, 20, "dof", generator) for _ in range(2000)])
    assert (draws.sum(1) == 20).all() and (draws >= 1).all()
    # one state each, the other 17 in proportion to 1 : 6 : 18
    expected = 1 + 17 * torch.tensor(dofs) / sum(dofs)
    assert torch.allclose(draws.float().mean(0), expected, atol=0.15)
    assert hand_counts(dofs, 20, "even", generator).tolist() in ([7, 7, 6], [7, 6, 7], [6, 7, 7])
    with pytest.raises(ValueError, match="valid: dof, even"):
        hand_counts(dofs, 20, "uniform", generator)


def test_hands_being_added_get_half_of_every_batch():
    galr, generator = tiny_galr(), torch.Generator().manual_seed(0)
    batch = sample_batch(galr, HANDS, 21, generator, "even", focus=(HANDS[-1],))
    sizes = {name: rows.stop - rows.start for name, rows, _ in batch.groups}
    assert sizes[HANDS[-1]] == 10 and sum(sizes.values()) == 21


def test_masked_loss_ignores_joints_a_hand_lacks():
    galr = tiny_galr().train()
    batch = sample_batch(galr, ["inspire"], 6, torch.Generator().manual_seed(0), "dof")
    loss, per_hand = masked_rmse(galr, batch, galr(*batch.encoder_inputs()))
    loss.backward()
    output = galr.decoder[-1]
    used = load_hand("inspire").universal_index
    unused = torch.ones(output.out_features, dtype=torch.bool)
    unused[used] = False
    assert output.weight.grad[unused].abs().max() == 0 and output.bias.grad[unused].abs().max() == 0
    assert output.weight.grad[used].abs().max() > 0
    assert set(per_hand) == {"inspire"}


def test_save_load_round_trip_identical(tmp_path):
    galr = tiny_galr(semantic_embedding="table")
    galr.save_pretrained(tmp_path)
    loaded = Galr.from_pretrained(tmp_path).eval()
    config = json.loads((tmp_path / "config.json").read_text())
    assert [h["name"] for h in config["hands"]] == HANDS and len(config["universal_joints"]) == 28
    assert all(len(h["sha256"]) == 64 for h in config["hands"])
    q = _joints("leap", 4)
    z = galr.encode_joints("leap", q)
    assert torch.equal(z, loaded.encode_joints("leap", q))
    assert torch.equal(galr.decode(z, "leap"), loaded.decode(z, "leap"))


def test_unknown_or_changed_hand_is_a_clear_error(tmp_path):
    galr = tiny_galr()
    with pytest.raises(ValueError, match="'shadow' is not in this GaLR checkpoint's registry"):
        galr.encode_joints("shadow", _joints("shadow", 1))
    changed = tmp_path / "umi"
    shutil.copytree(hand_models_dir() / "umi", changed)
    spec = (changed / "spec.yaml").read_text().replace("left_jaw_joint: 0.044}", "left_jaw_joint: 0.04}")
    (changed / "spec.yaml").write_text(spec)  # an expert pose: the GaLR does not depend on it
    galr.encode_joints(HandModel.from_spec(changed / "spec.yaml"), _joints("umi", 1))
    coupled = tmp_path / "umi_coupled"
    shutil.copytree(changed, coupled)
    (coupled / "spec.yaml").write_text(spec.replace("scale: 1.0", "scale: 0.9"))  # a coupling: it does
    with pytest.raises(ValueError, match="hand 'umi' changed since this GaLR checkpoint was trained"):
        galr.encode_joints(HandModel.from_spec(coupled / "spec.yaml"), _joints("umi", 1))


def _pretrain_config(output_dir: Path, steps: int, resume: bool = False) -> PretrainConfig:
    return PretrainConfig(
        output_dir=output_dir, hands=["umi", "inspire"], steps=steps, batch_size=6, validate_every=2,
        save_every=2,
        validation_states=4, warmup_steps=2, resume=resume, model=GalrConfig(**TINY),
    )  # fmt: skip


def _losses(output_dir: Path) -> dict[int, float]:
    rows = [json.loads(line) for line in (output_dir / "metrics.jsonl").read_text().splitlines()]
    return {r["step"]: r["train/loss"] for r in rows if "train/loss" in r}


def test_resume_continues_from_the_same_step(tmp_path):
    straight, interrupted = tmp_path / "straight", tmp_path / "interrupted"
    pretrain(_pretrain_config(straight, 4))
    pretrain(_pretrain_config(interrupted, 2))
    with pytest.raises(FileExistsError, match="--resume"):
        pretrain(_pretrain_config(interrupted, 4))
    pretrain(_pretrain_config(interrupted, 4, resume=True))
    assert sorted(_losses(interrupted)) == [1, 2, 3, 4]
    assert _losses(interrupted) == pytest.approx(_losses(straight), rel=1e-5)
    state = torch.load(interrupted / "checkpoints" / "step_0000004" / "training_state.pt", weights_only=False)
    assert state["step"] == 4
    a, b = Galr.from_pretrained(straight).state_dict(), Galr.from_pretrained(interrupted).state_dict()
    assert all(torch.allclose(a[k], b[k], atol=1e-6) for k in a)


def _cli_here(capsys, *args: str) -> subprocess.CompletedProcess:
    """`lerobot-opfa` run in this process (test_cli runs the installed command)."""
    from lerobot_opfa import cli

    code = cli.main(list(args))
    out = capsys.readouterr()
    return subprocess.CompletedProcess(["lerobot-opfa", *args], code, out.out, out.err)


def test_cli_pretrain_eval_embed_decode(tmp_path, capsys):
    run = tmp_path / "galr"
    pretrain = ["galr", "pretrain", "--hands", "umi,inspire", "--steps", "3", "--batch-size", "4",
                "--validate-every", "3", "--output-dir", str(run), "--model", *TINY_ARGS]  # fmt: skip
    result = _cli_here(capsys, *pretrain)
    assert result.returncode == 0, result.stderr[-2000:]
    assert (run / "model.safetensors").is_file() and (run / "checkpoints" / "step_0000003").is_dir()

    report_path, plot = tmp_path / "eval.json", tmp_path / "eval.png"
    clouds = str(tmp_path / "clouds.png")
    result = _cli_here(capsys, "galr", "eval", "--checkpoint", str(run), "--states", "8", "--json",
                       str(report_path), "--plot", str(plot), "--clouds", clouds)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads(report_path.read_text())
    assert set(report["hands"]) == {"umi", "inspire"}
    direct = evaluate(Galr.from_pretrained(run).eval(), ["umi", "inspire"], 8, seed=1)  # the CLI's defaults
    for hand, metrics in report["hands"].items():
        assert metrics["joint_rmse_deg"] == pytest.approx(direct["hands"][hand]["joint_rmse_deg"])
        assert metrics["fingertip_error_mm"] == pytest.approx(direct["hands"][hand]["fingertip_error_mm"])
    assert "prismatic_rmse_mm" in report["hands"]["umi"]
    assert plot.read_bytes()[:4] == b"\x89PNG" and (tmp_path / "clouds.png").is_file()

    joints = _joints("inspire", 5).numpy()
    np.save(tmp_path / "q.npy", joints)
    q_file = str(tmp_path / "q.npy")
    result = _cli_here(capsys, "galr", "embed", "--checkpoint", str(run), "--hand", "inspire", "--joints",
                       q_file, "--out", str(tmp_path / "z.npy"))  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    assert np.load(tmp_path / "z.npy").shape == (5, 16)
    result = _cli_here(capsys, "galr", "decode", "--checkpoint", str(run), "--hand", "inspire", "--latents",
                       str(tmp_path / "z.npy"), "--out", str(tmp_path / "q_hat.npy"))  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    assert np.load(tmp_path / "q_hat.npy").shape == (5, 6)
    result = _cli_here(capsys, "galr", "embed", "--checkpoint", str(run), "--hand", "leap", "--joints",
                       q_file, "--out", str(tmp_path / "bad.npy"))  # fmt: skip
    assert result.returncode == 2 and "not in this GaLR checkpoint's registry" in result.stderr
