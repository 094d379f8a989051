"""A user's mistakes with datasets, joint maps, merges and writers are refused in one line before any work,
and nothing is lost or left half-written (issue 42): concurrent writers, a full disk, LeRobot's own editing
tools, maps of the wrong hand or units, merges without a shared camera, maps bound to inputs."""

from __future__ import annotations

import errno
import gc
import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.dataset_writer import DatasetWriter
from lerobot.utils.constants import ACTION, OBS_STATE
from subprocesses import run_lerobot_here
from test_joint_maps import N_POINTS, robot_dataset, write_map
from test_policy import make_policy, save_galr

from lerobot_opfa import cli
from lerobot_opfa.datasets.io import atomic_directory, new_dataset, read_columns
from lerobot_opfa.datasets.joint_map import JointMap, JointMapError
from lerobot_opfa.datasets.layout import OPFA_META_FILE, opfa_record, read_layout
from lerobot_opfa.datasets.synthetic import WRIST_NAMES, write_synthetic_dataset
from lerobot_opfa.features import OBS_EMBODIMENT
from lerobot_opfa.hands import load_hand


def _siblings(output: Path) -> list[str]:
    return sorted(p.name for p in output.parent.iterdir() if p.name.startswith(f".{output.name}."))


def _one_line(capsys) -> str:
    """The error the CLI printed: its last line (above it only progress bars), with no traceback."""
    err = capsys.readouterr().err.strip()
    assert err.splitlines()[-1].startswith("error: ") and "Traceback" not in err, err
    return err.splitlines()[-1]


# --- writers ------------------------------------------------------------------------------------------


def test_an_output_that_appears_while_writing_is_kept_not_replaced(tmp_path):
    """Two runs to one output without --overwrite: the one that finishes second is refused, and the first's
    dataset stays whole."""
    output = tmp_path / "merged"
    create = dict(repo_id="local/merged", fps=10, features={}, robot_type="umi", use_videos=False)
    with pytest.raises(FileExistsError, match="appeared while this run was writing it") as error:
        with new_dataset(output, **create):
            # the other run, in another process, finishes first: its partial folder becomes the output
            write_synthetic_dataset(tmp_path / "other", "umi", episodes=1, frames=3, n_points=4)
            (tmp_path / "other").rename(output)
    assert "\n" not in str(error.value)
    assert LeRobotDatasetMetadata("local/merged", root=output).total_episodes == 1
    assert read_columns(output, [OBS_STATE])[OBS_STATE].shape == (3, 7), "the first run's dataset, whole"
    assert _siblings(output) == []
    with pytest.raises(FileExistsError, match="appeared while"), atomic_directory(tmp_path / "x") as partial:
        partial.mkdir()
        (tmp_path / "x").mkdir()
        (tmp_path / "x" / "kept").write_text("first")
    assert (tmp_path / "x" / "kept").read_text() == "first"


def test_a_full_disk_leaves_nothing_behind_and_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    """ENOSPC when LeRobot's writer closes its data file: its retried `finalize` fails again; the
    metadata's buffered episodes must not be flushed into the deleted partial folder afterwards."""

    def disk_full(self):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(DatasetWriter, "close_writer", disk_full)
    output = tmp_path / "demos"
    assert cli.main(["dataset", "synthetic", "--hand", "umi", "--output", str(output), "--episodes", "2",
                     "--frames", "3", "--n-points", "4"]) == 2  # fmt: skip
    err = _one_line(capsys)
    assert f"{output} was not written: the disk is full" in err
    gc.collect()  # LeRobot flushes what its metadata buffered when the dataset is collected
    assert not output.exists() and list(tmp_path.iterdir()) == []


# --- plugin metadata through LeRobot's own editing tools ---------------------------------------------


@pytest.fixture(scope="module")
def merged(tmp_path_factory) -> Path:
    """A tiny GaLR, two hands' synthetic datasets and their merge with cached latents."""
    root = tmp_path_factory.mktemp("merged")
    save_galr(root / "galr", ["umi", "inspire"])
    for seed, hand in enumerate(["umi", "inspire"]):
        write_synthetic_dataset(root / hand, hand, episodes=2, frames=8, n_points=16, seed=seed)
    inputs = [str(root / "umi"), str(root / "inspire")]
    merge = ["dataset", "merge", "--inputs", *inputs, "--output", str(root / "merged")]
    assert cli.main([*merge, "--galr", str(root / "galr")]) == 0
    return root


def _delete_episodes(root: Path, output: Path, episodes: list[int]) -> None:
    """LeRobot's `lerobot-edit-dataset --operation.type=delete_episodes`, its entry point run in this
    process."""
    argv = [f"--repo_id=local/{root.name}", f"--root={root}", f"--new_root={output}",
            "--operation.type=delete_episodes", f"--operation.episode_indices={episodes}"]  # fmt: skip
    with pytest.MonkeyPatch.context() as monkeypatch:
        run_lerobot_here("lerobot_edit_dataset", argv, monkeypatch)


def test_the_record_survives_lerobot_edit_dataset(merged, tmp_path):
    """`lerobot-edit-dataset` rewrites meta/ without meta/opfa.json; the copy in meta/info.json's features
    stays, so the edited dataset still names the GaLR of its cached latents (and a clouds dataset its
    calibration)."""
    edited = tmp_path / "edited"
    _delete_episodes(merged / "merged", edited, [1])
    assert not (edited / OPFA_META_FILE).exists(), "LeRobot drops the plugin's file"
    record = json.loads((merged / "merged" / OPFA_META_FILE).read_text())
    assert opfa_record(edited) == record and record["galr_fingerprint"]
    meta = LeRobotDatasetMetadata("local/edited", root=edited)
    layout = read_layout(meta.features, meta.robot_type, edited)
    assert layout.galr_fingerprint == record["galr_fingerprint"] and layout.latent_dim > 0
    assert meta.total_episodes == 3


def test_a_merge_whose_record_is_gone_is_refused(merged, tmp_path):
    """A dataset merged before info.json kept the copy, then edited: its cached latents are of a GaLR
    nothing names any more; training would fall back to the default GaLR without a word."""
    old = tmp_path / "old"
    _delete_episodes(merged / "merged", old, [0])
    info = json.loads((old / "meta" / "info.json").read_text())
    info["features"][OBS_STATE].pop("info", None)
    (old / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    meta = LeRobotDatasetMetadata("local/old", root=old)
    with pytest.raises(ValueError, match="holds latents cached by .* but not its meta/opfa.json") as error:
        read_layout(meta.features, meta.robot_type, old)
    assert "\n" not in str(error.value) and "merge the inputs again" in str(error.value)


def test_a_dataset_without_a_record_keeps_no_stale_copy(merged, tmp_path):
    """`policy latent-dataset` copies its input's features; its own record replaces the inherited copy."""
    argv = ["policy", "latent-dataset", "--input", str(merged / "merged"), "--output", str(tmp_path / "z")]
    assert cli.main(argv) == 0
    assert opfa_record(tmp_path / "z")["policy_space"] is True
    info = json.loads((merged / "umi" / "meta" / "info.json").read_text())
    assert "info" not in info["features"][OBS_STATE], "a dataset without a record has no copy"
    assert ACTION in info["features"] and np.ndim(info["features"][OBS_STATE]["shape"]) == 1


def test_a_hand_whose_episodes_were_all_deleted_is_named_as_such(merged):
    """Deleting every episode of one hand from a merge leaves the hand listed without frames: the error
    says so, not that its episodes are too short."""
    _delete_episodes(merged / "merged", merged / "no_inspire", [2, 3])  # the merge's inspire episodes
    with pytest.raises(ValueError, match="has no episode of hand 'inspire'") as error:
        make_policy(merged, "no_inspire", action_space="galr")
    assert "\n" not in str(error.value) and "delete_episodes" in str(error.value)


# --- joint maps and merges ---------------------------------------------------------------------------

SIX = [f"hand.j{i}" for i in range(6)]
"""Two robots, one with an Inspire hand and one with an Ability hand, name their six actuators alike."""


@pytest.fixture(scope="module")
def robots(tmp_path_factory) -> Path:
    """`so101_inspire` and `so101_ability`: robots' datasets (radians) with the same entry names, and a map
    for each hand."""
    root = tmp_path_factory.mktemp("robots")
    save_galr(root / "galr", ["inspire", "ability"])
    for seed, hand in enumerate(["inspire", "ability"]):
        write_synthetic_dataset(
            root / f"{hand}_sim", hand, episodes=2, frames=8, n_points=N_POINTS, seed=seed
        )
        entries = dict(zip(SIX, load_hand(hand).joint_names, strict=True))
        robot_dataset(root / f"{hand}_sim", root / f"so101_{hand}", f"so101_{hand}", entries, {}, body=[])
        write_map(root / f"{hand}.yaml", hand, entries)
    return root


def _merge(robots: Path, output: Path, inputs: list[str], maps: list[str]) -> int:
    roots = [str(robots / i) for i in inputs]
    return cli.main(["dataset", "merge", "--inputs", *roots, "--output", str(output), "--joint-maps", *maps])


def test_closest_entry_names_are_quoted(robots):
    """A trailing space in a map's entry is visible in the message."""
    meta = LeRobotDatasetMetadata("local/so101_inspire", root=robots / "so101_inspire")
    joints = load_hand("inspire").joint_names
    path = write_map(robots.parent / "spaced.yaml", "inspire", dict(zip(SIX, joints, strict=True)))
    path.write_text(path.read_text().replace("  hand.j0:", '  "hand.j0 ":'))
    with pytest.raises(JointMapError, match="entry 'hand.j0 ' is not in .* \\(closest: 'hand.j0', "):
        JointMap.load(path).bind(meta.features[OBS_STATE]["names"], meta.features[ACTION]["names"])


def test_a_map_for_another_hand_than_the_robot_type_names_is_refused(robots, tmp_path, capsys):
    """`hand: ability` on the data of a robot whose robot_type names the Inspire: its values lie within the
    Ability's limits, so nothing else would notice."""
    assert _merge(robots, tmp_path / "m", ["so101_inspire"], [str(robots / "ability.yaml")]) == 2
    err = _one_line(capsys)
    assert "maps hand 'ability', but the dataset's robot_type 'so101_inspire' names hand 'inspire'" in err
    assert "robot_type: so101_inspire" in err and str(robots / "ability.yaml") in err
    confirmed = tmp_path / "confirmed.yaml"
    confirmed.write_text((robots / "ability.yaml").read_text() + "robot_type: so101_inspire\n")
    assert _merge(robots, tmp_path / "m", ["so101_inspire"], [str(confirmed)]) == 0, "confirmed deliberately"
    assert _merge(robots, tmp_path / "i", ["so101_inspire"], [str(robots / "inspire.yaml")]) == 0


def test_a_scale_that_squeezes_a_joint_is_refused(robots, tmp_path, capsys):
    """A degrees scale on entries already in radians puts every value within the limits, at a tenth of the
    range: refused in the merge and in training."""
    joints = load_hand("inspire").joint_names
    degrees = {joint: (0.0174533, 0.0) for joint in joints}
    path = write_map(tmp_path / "degrees.yaml", "inspire", dict(zip(SIX, joints, strict=True)), degrees)
    assert _merge(robots, tmp_path / "m", ["so101_inspire"], [str(path)]) == 2
    err = _one_line(capsys)
    assert "entry 'hand.j0' with scale 0.0174533 moves joint 'thumb_yaw' over 0.0" in err
    assert "of its range 1.31 ([0, 1.31])" in err and "use scale 1" in err
    with pytest.raises(JointMapError, match="with scale 0.0174533 moves joint 'thumb_yaw'"):
        make_policy(robots, "so101_inspire", action_space="raw", joint_map=str(path))


def test_two_robots_named_alike_merge_with_a_map_bound_to_each(robots, tmp_path, capsys):
    inputs = ["so101_inspire", "so101_ability"]
    maps = [str(robots / "inspire.yaml"), str(robots / "ability.yaml")]
    assert _merge(robots, tmp_path / "m", inputs, maps) == 2
    assert f"bind one to it: --joint-maps {robots / 'so101_inspire'}=MAP" in _one_line(capsys)
    assert _merge(robots, tmp_path / "m", inputs, [f"{robots / 'nowhere'}={maps[0]}"]) == 2
    assert "not a map file, nor INPUT=MAP with INPUT one of --inputs" in _one_line(capsys)
    bound = [f"{robots / i}={m}" for i, m in zip(inputs, maps, strict=True)]
    assert _merge(robots, tmp_path / "m", inputs, bound) == 0
    meta = LeRobotDatasetMetadata("local/m", root=tmp_path / "m")
    assert meta.features[OBS_EMBODIMENT]["names"] == ["inspire", "ability"]
    merged = read_columns(tmp_path / "m", [OBS_STATE, OBS_EMBODIMENT])
    for index, hand in enumerate(["inspire", "ability"]):
        sim = read_columns(robots / f"{hand}_sim", [OBS_STATE])[OBS_STATE][:, 6:]
        universal = load_hand(hand).to_universal(torch.tensor(sim)).numpy()
        rows = merged[OBS_EMBODIMENT].reshape(-1) == index
        assert np.allclose(merged[OBS_STATE][rows, : universal.shape[1]], universal, atol=1e-5), hand


def _camera_dataset(root: Path, cameras: list[str]) -> Path:
    """A one-episode umi dataset with the given RGB cameras and no cloud."""
    names = [*WRIST_NAMES, *load_hand("umi").joint_names]
    image = {"dtype": "image", "shape": (8, 8, 3), "names": ["height", "width", "channels"]}
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (len(names),), "names": names},
        ACTION: {"dtype": "float32", "shape": (len(names),), "names": names},
        **dict.fromkeys(cameras, image),
    }
    create = dict(repo_id=f"local/{root.name}", fps=10, features=features, robot_type="umi", use_videos=False)
    with new_dataset(root, **create) as dataset:
        for t in range(3):
            state = np.full(len(names), 0.01 * t, np.float32)
            frame = {OBS_STATE: state, ACTION: state, "task": "reach"}
            dataset.add_frame(frame | {key: np.full((8, 8, 3), 40 * t, np.uint8) for key in cameras})
        dataset.save_episode()
    return root


def test_a_merge_of_inputs_that_share_no_camera_is_refused(tmp_path, capsys):
    left = _camera_dataset(tmp_path / "left", ["observation.images.left"])
    right = _camera_dataset(tmp_path / "right", ["observation.images.right", "observation.images.wrist"])
    merge = ["dataset", "merge", "--inputs", str(left), str(right), "--output"]
    assert cli.main([*merge, str(tmp_path / "m")]) == 2
    err = _one_line(capsys)
    assert "the inputs share no camera or point cloud" in err
    assert (
        f"{left}: observation.images.left; {right}: observation.images.right, observation.images.wrist" in err
    )
    assert not (tmp_path / "m").exists()
    numeric = [_camera_dataset(tmp_path / f"numeric{i}", []) for i in range(2)]
    assert (
        cli.main(["dataset", "merge", "--inputs", *map(str, numeric), "--output", str(tmp_path / "n")]) == 0
    )


def test_a_map_that_fits_no_input_names_its_missing_entry_and_the_closest(tmp_path, capsys):
    demos = write_synthetic_dataset(tmp_path / "inspire", "inspire", n_points=N_POINTS)
    names = LeRobotDatasetMetadata("local/inspire", root=demos).features[OBS_STATE]["names"]
    entries = {name: {"joint": name} for name in names[len(WRIST_NAMES) :]}
    entries["thumb_benx"] = entries.pop("thumb_bend")
    typo = tmp_path / "typo.yaml"
    typo.write_text(json.dumps({"hand": "inspire", "joints": entries}))  # JSON is YAML
    merge = ["dataset", "merge", "--inputs", str(demos), "--output", str(tmp_path / "out"), "--joint-maps"]
    assert cli.main([*merge, str(typo)]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"in {demos}, the closest, entry 'thumb_benx' (did you mean 'thumb_bend'?)" in error, error
