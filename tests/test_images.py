"""The policy's colour cameras: the image encoder, the choice of visual inputs and its errors."""

from __future__ import annotations

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_opfa.flags import FlagError
from lerobot_opfa.policy.configuration_opfa import OpfaConfig
from lerobot_opfa.policy.image_encoder import ImageEncoder, SpatialSoftmax

STATE = PolicyFeature(FeatureType.STATE, (7,))
ACTION = {"action": PolicyFeature(FeatureType.ACTION, (7,))}
RGB = PolicyFeature(FeatureType.VISUAL, (3, 48, 64))
DEPTH = PolicyFeature(FeatureType.VISUAL, (1, 48, 64))


def config(visual_inputs: str, **inputs: PolicyFeature) -> OpfaConfig:
    features = {"observation.state": STATE} | {k.replace("__", "."): v for k, v in inputs.items()}
    return OpfaConfig(visual_inputs=visual_inputs, input_features=features, output_features=dict(ACTION))


@pytest.mark.parametrize("backbone", ["small", "resnet18"])
def test_the_encoder_gives_features_of_its_width_with_a_random_crop_in_training_only(backbone):
    torch.manual_seed(0)
    encoder = ImageEncoder((3, 48, 64), out_dim=16, backbone=backbone)
    images = torch.rand(3, 3, 48, 64)
    assert encoder(images).shape == (3, 16)
    encoder.eval()
    assert torch.equal(encoder(images), encoder(images))  # the centre crop
    encoder.train()
    crops = {tuple(encoder._crop(images)[0, 0, 0, :3].tolist()) for _ in range(20)}
    assert len(crops) > 1 and encoder._crop(images).shape[-2:] == (43, 58)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in encoder.modules())


def test_spatial_softmax_finds_a_bright_spot():
    layer = SpatialSoftmax(1, 5, 5, keypoints=1)
    with torch.no_grad():
        layer.to_keypoints.weight.fill_(50.0)
        layer.to_keypoints.bias.zero_()
    features = torch.zeros(1, 1, 5, 5)
    features[0, 0, 4, 0] = 1.0  # bottom-left corner
    assert torch.allclose(layer(features), torch.tensor([[[-1.0, 1.0]]]), atol=1e-3)


def test_rgb_reads_the_colour_cameras_only_and_keeps_no_camera_it_does_not_read():
    cfg = config("rgb", observation__images__front_rgb=RGB, observation__images__front_depth=DEPTH)
    cfg.validate_features()
    assert cfg.image_keys == ["observation.images.front_rgb"]
    assert set(cfg.input_features) == {"observation.state", "observation.images.front_rgb"}
    cloud = PolicyFeature(FeatureType.STATE, (30,))
    cfg = config("pointcloud", observation__pointcloud=cloud, observation__images__front_rgb=RGB)
    cfg.validate_features()
    assert cfg.image_keys == [] and "observation.images.front_rgb" not in cfg.input_features


@pytest.mark.parametrize(
    ("visual_inputs", "inputs", "message"),
    [
        ("rgb", {"observation__images__front_depth": DEPTH}, "needs colour cameras"),
        ("pointcloud_rgb", {"observation__images__front_rgb": RGB}, "missing ['observation.pointcloud']"),
        (
            "rgb",
            {
                "observation__images__a": RGB,
                "observation__images__b": PolicyFeature(FeatureType.VISUAL, (3, 24, 32)),
            },
            "differ in size",
        ),  # fmt: skip
    ],
)
def test_visual_inputs_without_what_they_read_are_one_line_errors(visual_inputs, inputs, message):
    with pytest.raises(ValueError, match=None) as err:
        config(visual_inputs, **inputs).validate_features()
    assert message in str(err.value) and "\n" not in str(err.value)


def test_unknown_visual_inputs_and_backbones_list_the_valid_ones():
    with pytest.raises(FlagError, match="`visual_inputs` must be one of"):  # as a --policy.* flag
        OpfaConfig(visual_inputs="depth")
    with pytest.raises(FlagError, match="`image_backbone` must be one of"):
        OpfaConfig(image_backbone="resnet50")


def test_images_too_small_for_keypoints_are_an_error():
    with pytest.raises(ValueError, match="8x8 leave the small backbone a 1x1 feature map"):
        ImageEncoder((3, 8, 8))
