"""Neural networks for the camera: Racecraft's compact and lean networks and DeepRacer's CNNs,
as SB3 extractors.

Every network takes the car's 160×120 grayscale camera (``C`` channels: 1 mono, 2 stereo) as
SB3 hands it over: ``(batch, C, 120, 160)`` floats in 0..1. Racecraft's networks average the
pixels inside the network first, so the exported model still takes 160×120 images: the lean
network 2×2 (80×60; on a 2-core CPU it trains about 10× faster than DeepRacer's 3-layer CNN at
full size), the compact one 4×4 (40×30), with fewer filters and dense units behind: its update
costs about 0.6 of the lean network's, and the racing preset learns its fast laps in fewer
steps with it (docs/benchmarks.md, "The compact network").

With a LIDAR the observation is a ``Dict`` keyed by DeepRacer's sensor ids and the policy is
SB3's ``MultiInputPolicy`` with :class:`CameraLidarExtractor`: the camera network as above and,
as DeepRacer builds it (deepracer-spec §4), a LIDAR embedder of two 256-unit dense layers,
their features concatenated. A camera-only model keeps :class:`CameraExtractor` and its
weight names, so existing checkpoints and exports are unchanged.
"""

from __future__ import annotations

import itertools

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

LEAN = "RACECRAFT_LEAN_CNN"
COMPACT = "RACECRAFT_COMPACT_CNN"
SHALLOW = "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
STANDARD = "DEEP_CONVOLUTIONAL_NETWORK"
DEEP = "DEEP_CONVOLUTIONAL_NETWORK_DEEP"
AWS_SHALLOW = "AWS_DEEPRACER_3_LAYER_CNN"
AWS_STANDARD = "AWS_DEEPRACER_5_LAYER_CNN"
TINY = "RACECRAFT_TINY_TEST_CNN"
"""A network for the test suite only: 8×8 pooling (20×15), one convolution of 4 filters and a
16-unit dense layer, about 4 000 weights, where a test's subject is not the network itself.
It is never offered to users: it is not in :data:`NETWORKS` (what ``model_metadata.json``
accepts, so no form, import or model row can name it), :data:`NETWORK_LABELS` (the form's
choices) or :data:`SPECS` (what imported DeepRacer graphs and checkpoints are matched
against); only the builders here (:func:`policy_kwargs`, :func:`sac_policy_kwargs`, the
extractors, hence ``TrainingConfig(network=TINY)`` and ``build_model(..., network=TINY)``)
know it."""
NETWORKS = (COMPACT, LEAN, SHALLOW, STANDARD, DEEP, AWS_SHALLOW, AWS_STANDARD)
NETWORK_LABELS = {
    COMPACT: "Racecraft compact CNN (pooled 40×30, fastest on a CPU)",
    LEAN: "Racecraft lean CNN (pooled 80×60)",
    SHALLOW: "DeepRacer 3-layer CNN",
    STANDARD: "DeepRacer 5-layer CNN",
    DEEP: "DeepRacer deep CNN",
    AWS_SHALLOW: "DeepRacer 3-layer CNN, heads as in AWS (imported DeepRacer models)",
    AWS_STANDARD: "DeepRacer 5-layer CNN, heads as in AWS (imported DeepRacer models)",
}
DEEPRACER_NAMES = {
    COMPACT: SHALLOW,
    LEAN: SHALLOW,
    SHALLOW: SHALLOW,
    STANDARD: STANDARD,
    DEEP: DEEP,
    AWS_SHALLOW: SHALLOW,
    AWS_STANDARD: STANDARD,
    TINY: SHALLOW,  # never exported for a user; should a test export one, its metadata is valid
}
"""The ``neural_network`` value DeepRacer's tools accept for each network (the car ignores it;
DeepRacer-for-Cloud and the SimApp refuse names they do not know)."""
DIRECT_HEADS = (AWS_SHALLOW, AWS_STANDARD)
"""Networks whose policy and value heads sit right on the dense layer, as in DeepRacer's own
models (Racecraft's other networks put a 64-unit hidden layer before each head)."""


class NetworkError(ValueError):
    """An unknown network name."""


def _conv_stack(channels: int, spec: list[tuple[int, int, int]], pool: int = 1) -> nn.Sequential:
    layers: list[nn.Module] = [nn.AvgPool2d(pool)] if pool > 1 else []
    for filters, kernel, stride in spec:
        layers += [nn.Conv2d(channels, filters, kernel, stride), nn.ReLU()]
        channels = filters
    layers.append(nn.Flatten())
    return nn.Sequential(*layers)


SPECS: dict[str, tuple[int, list[tuple[int, int, int]], int]] = {
    # name: (pooling, [(filters, kernel, stride)], dense units)
    COMPACT: (4, [(16, 4, 2), (16, 4, 2)], 128),
    LEAN: (2, [(16, 8, 4), (32, 4, 2)], 256),
    SHALLOW: (1, [(32, 8, 4), (64, 4, 2), (64, 3, 1)], 512),
    STANDARD: (1, [(32, 5, 2), (32, 3, 1), (64, 3, 2), (64, 3, 1)], 512),
    DEEP: (1, [(32, 8, 4), (32, 4, 2), (64, 4, 2), (64, 3, 1)], 512),
}
SPECS[AWS_SHALLOW] = SPECS[SHALLOW]
SPECS[AWS_STANDARD] = SPECS[STANDARD]
TEST_SPECS: dict[str, tuple[int, list[tuple[int, int, int]], int]] = {
    # (C, 120, 160) -> pooled (C, 15, 20) -> conv 3×3 stride 2: (4, 7, 9) = 252 -> 16 units
    TINY: (8, [(4, 3, 2)], 16),
}
"""Networks for tests only (:data:`TINY`), kept out of :data:`SPECS` so that an uploaded
graph of the same shapes is not taken for one."""


def network_spec(network: str) -> tuple[int, list[tuple[int, int, int]], int]:
    """``(pooling, [(filters, kernel, stride)], dense units)`` of a network name, the test-only
    ones included; raises :class:`NetworkError` for an unknown name."""
    spec = SPECS.get(network) or TEST_SPECS.get(network)
    if spec is None:
        raise NetworkError(f"unknown network {network!r}; choose from {NETWORKS}")
    return spec


def average_pool(images: torch.Tensor, size: int) -> torch.Tensor:
    """``nn.AvgPool2d(size)`` of ``images`` (batch, C, H, W), bit for bit, in about a third of
    its time on a CPU (8 camera frames: 0.08 against 0.27 ms, measured on a 2-core AMD EPYC).

    torch's CPU kernel adds each window's pixels row by row, left to right, from zero, then
    divides by ``size²``; this adds the same pixels in the same order, a strided slice of the
    whole batch at a time, so every sum rounds as the kernel's does
    (tests/training/rl/test_fast_paths.py holds the two equal). Rows and columns past the last
    whole window are dropped, as the layer drops them."""
    rows, cols = images.shape[-2] // size * size, images.shape[-1] // size * size
    window = images[..., :rows, :cols]
    total = None
    for dy in range(size):
        for dx in range(size):
            part = window[..., dy::size, dx::size]
            total = part if total is None else total + part
    return total / (size * size)


FAST_POOLING = 2
"""The averaging that :func:`average_pool` does faster than the layer: the lean network's 2×2
(8×8 takes 64 slices, four times the layer's time)."""


def _tracing() -> bool:
    return torch.jit.is_tracing() or torch.onnx.is_in_onnx_export()


class CameraExtractor(BaseFeaturesExtractor):
    """Convolutions over the camera image, then one dense layer."""

    def __init__(self, observation_space: gym.spaces.Box, network: str = LEAN) -> None:
        pool, spec, dense = network_spec(network)
        super().__init__(observation_space, features_dim=dense)
        channels = observation_space.shape[0]
        self.cnn = _conv_stack(channels, spec, pool)
        with torch.no_grad():
            sample = torch.zeros(1, *observation_space.shape)
            flat = self.cnn(sample).shape[1]
        self.linear = nn.Sequential(nn.Linear(flat, dense), nn.ReLU())
        self.network = network
        self.pooling = pool
        self._last_conv = max(i for i, layer in enumerate(self.cnn) if isinstance(layer, nn.Conv2d))

    def prepare(self, images: torch.Tensor) -> torch.Tensor:
        """The network's front that holds no weights: the pixel averaging (lean network), or
        the images as they are. A policy update runs it once per rollout (it is the same in
        every epoch) and feeds the result to :meth:`forward_prepared`. The averaging is
        :func:`average_pool` for 2×2 (the layer's numbers, faster), but for an export, which
        keeps the layer."""
        if self.pooling <= 1:
            return images
        if self.pooling != FAST_POOLING or _tracing():
            return self.cnn[0](images)
        return average_pool(images, self.pooling)

    def forward_prepared(self, prepared: torch.Tensor) -> torch.Tensor:
        """The rest of the network, from :meth:`prepare`'s output."""
        x = prepared
        # Not ``self.cnn[1:]``: slicing builds a new Sequential on every call (13 µs), and
        # this runs for every frame the cars see.
        start = 1 if self.pooling > 1 else 0
        for index, layer in enumerate(itertools.islice(self.cnn, start, None), start):
            x = layer(x)
            if index == self._last_conv and not x.is_contiguous() and not _tracing():
                # Channels-last weights (build_model) give a channels-last output, which the
                # flattening copies to torch's default layout anyway; copied before the ReLU
                # instead, the ReLU's gradient meets a gradient of its own layout: 0.33
                # against 0.04 ms a minibatch of 64 (lean network), the same numbers.
                x = x.contiguous()
        return self.linear(x)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return self.forward_prepared(self.prepare(observations))


LIDAR_EMBEDDER_UNITS = (256, 256)
"""DeepRacer's LIDAR embedder: two dense layers (ReLU) over the LIDAR vector."""
TEST_LIDAR_UNITS = {TINY: (16, 16)}
"""The LIDAR embedder of the test-only networks (every other network has DeepRacer's)."""


def split_sensors(space: gym.spaces.Dict) -> tuple[str, str]:
    """The camera's key and the LIDAR's key of a Dict observation space (the image is the
    3-dimensional subspace). Raises :class:`NetworkError` for any other layout."""
    images = [k for k, s in space.spaces.items() if len(s.shape or ()) == 3]
    vectors = [k for k, s in space.spaces.items() if len(s.shape or ()) == 1]
    if len(images) != 1 or len(vectors) != 1 or len(space.spaces) != 2:
        raise NetworkError(
            f"a Dict observation must hold one camera image and one LIDAR vector; got {space}"
        )
    return images[0], vectors[0]


class CameraLidarExtractor(BaseFeaturesExtractor):
    """The camera network (:class:`CameraExtractor`) and DeepRacer's LIDAR embedder side by
    side; the features are both concatenated (camera first)."""

    def __init__(self, observation_space: gym.spaces.Dict, network: str = LEAN) -> None:
        camera_key, lidar_key = split_sensors(observation_space)
        camera = CameraExtractor(observation_space.spaces[camera_key], network)
        size = int(observation_space.spaces[lidar_key].shape[0])
        layers: list[nn.Module] = []
        for units in TEST_LIDAR_UNITS.get(network, LIDAR_EMBEDDER_UNITS):
            layers += [nn.Linear(size, units), nn.ReLU()]
            size = units
        super().__init__(observation_space, features_dim=camera.features_dim + size)
        self.camera_key, self.lidar_key = camera_key, lidar_key
        self.camera = camera
        self.lidar = nn.Sequential(*layers)
        self.network = network

    @property
    def pooling(self) -> int:
        return self.camera.pooling

    def prepare(self, images: torch.Tensor) -> torch.Tensor:
        """The camera network's :meth:`CameraExtractor.prepare` (the camera's images only)."""
        return self.camera.prepare(images)

    def forward_prepared(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        """The features from the camera's prepared images and the LIDAR vector."""
        return torch.cat(
            [
                self.camera.forward_prepared(observations[self.camera_key]),
                self.lidar(observations[self.lidar_key]),
            ],
            dim=1,
        )

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        prepared = dict(observations)
        prepared[self.camera_key] = self.prepare(observations[self.camera_key])
        return self.forward_prepared(prepared)


def policy_type(observation_space: gym.spaces.Space | None) -> str:
    """SB3's policy name for an observation space: ``MultiInputPolicy`` for camera + LIDAR."""
    return "MultiInputPolicy" if isinstance(observation_space, gym.spaces.Dict) else "CnnPolicy"


def policy_kwargs(network: str = LEAN, observation_space: gym.spaces.Space | None = None) -> dict:
    """SB3 ``policy_kwargs`` for a network name (model_metadata.json's ``neural_network``) and
    the observation space (a ``Dict`` one adds the LIDAR embedder)."""
    network_spec(network)  # an unknown name raises NetworkError
    lidar = isinstance(observation_space, gym.spaces.Dict)
    return {
        "features_extractor_class": CameraLidarExtractor if lidar else CameraExtractor,
        "features_extractor_kwargs": {"network": network},
        "net_arch": {"pi": [], "vf": []} if network in DIRECT_HEADS else {"pi": [64], "vf": [64]},
        "normalize_images": True,
    }


def sac_policy_kwargs(
    network: str = LEAN, observation_space: gym.spaces.Space | None = None
) -> dict:
    """SB3 ``policy_kwargs`` of SAC for a network name and observation space."""
    kwargs = policy_kwargs(network, observation_space)
    kwargs["net_arch"] = {"pi": [] if network in DIRECT_HEADS else [64], "qf": [64]}
    return kwargs
