"""sfgs.Avatar: a trained avatar as a torch.nn.Module.

Its parameters and buffers are the C++ avatar's own tensors (not copies), held in submodules named as in the
checkpoint, so an optimiser, ``state_dict()`` / ``load_state_dict()``, ``train()`` / ``eval()`` and ``.to(device)``
act on the avatar that renders. After an in-place change of the parameters (an optimiser's step, a loaded state
dict) the next render makes its caches again.
"""
from typing import Any, Dict, List, Optional, Tuple, Union

import torch

from . import _C

Pose = Dict[str, Any]
Camera = Dict[str, Any]


def _holder(root: torch.nn.Module, path: List[str]) -> torch.nn.Module:
    """The submodule of `root` at `path`, made (empty) where missing."""
    module = root
    for name in path:
        child = module._modules.get(name)
        if child is None:
            child = torch.nn.Module()
            module._modules[name] = child
        module = child
    return module


def _restore(run: str, device: str, data: str, other_dataset: bool, state: Dict[str, torch.Tensor],
             training: bool) -> "Avatar":
    avatar = Avatar(_C.load_avatar(run, device, data, other_dataset))
    avatar.load_state_dict(state)
    return avatar.train(training)


class Avatar(torch.nn.Module):
    """A trained SFGS avatar (``sfgs.load_avatar(run)``): pose it, render it, fine-tune it.

    ``forward(camera, pose, background=None)`` is ``render(...)["image"]``. In eval mode (the default) renders use the
    observation prior and, on CUDA without a gradient, one CUDA graph replay a frame; in training mode every render is
    differentiable with respect to the parameters, as in training.
    """

    def __init__(self, avatar: _C.Avatar):
        super().__init__()
        self._avatar = avatar
        for parameters, table in ((True, "_parameters"), (False, "_buffers")):
            for name, tensor in avatar.named_tensors(parameters):
                *path, leaf = name.split(".")
                getattr(_holder(self, path), table)[leaf] = tensor
        super().train(avatar.training)

    # --- nn.Module -------------------------------------------------------------------------------------------------
    def forward(self, camera: Union[Camera, List[Camera]], pose: Union[Pose, List[Pose], None] = None,
                background: Optional[torch.Tensor] = None) -> torch.Tensor:
        return self.render(camera, {} if pose is None else pose, background)["image"]

    def train(self, mode: bool = True) -> "Avatar":
        self._avatar.set_training(mode)
        return super().train(mode)

    def to(self, *args, **kwargs) -> "Avatar":
        device, dtype, non_blocking, memory_format = torch._C._nn._parse_to(*args, **kwargs)
        if dtype is not None and dtype != torch.float32:
            raise TypeError(f"Avatar.to: the avatar's parameters are float32; got dtype {dtype}")
        if device is not None:
            self._avatar.move_to(torch.device(device).type)
        return self

    def cuda(self, device: Optional[Union[int, torch.device]] = None) -> "Avatar":
        return self.to("cuda")

    def cpu(self) -> "Avatar":
        return self.to("cpu")

    def _apply(self, fn, *args, **kwargs):
        raise TypeError("Avatar: only .to(device), .cuda() and .cpu() convert it (its parameters stay float32 and "
                        "are the C++ avatar's own tensors)")

    def __reduce__(self):
        state = {name: tensor.detach().cpu().clone() for name, tensor in self.state_dict().items()}
        return (_restore, (self._avatar.run, self._avatar.device, self._avatar.data, self._avatar.other_dataset, state,
                           self.training))

    # --- the avatar ------------------------------------------------------------------------------------------------
    def render(self, camera: Union[Camera, List[Camera]], pose: Union[Pose, List[Pose], None] = None,
               background: Optional[torch.Tensor] = None) -> Dict[str, torch.Tensor]:
        return self._avatar.render(camera, {} if pose is None else pose, background)

    def gaussians(self, pose: Optional[Pose] = None) -> Dict[str, torch.Tensor]:
        return self._avatar.gaussians({} if pose is None else pose)

    def training_loss(self, camera: Camera, pose: Pose, image: torch.Tensor, *, mask: Optional[torch.Tensor] = None,
                      background: Optional[torch.Tensor] = None, lpips: bool = True) -> Dict[str, torch.Tensor]:
        return self._avatar.training_loss(camera, pose, image, mask=mask, background=background, lpips=lpips)

    def centre(self, pose: Optional[Pose] = None) -> Tuple[float, float, float]:
        return self._avatar.centre({} if pose is None else pose)

    def frame(self, index: int) -> Dict[str, Any]:
        return self._avatar.frame(index)

    def motion(self, path: str, fps: float = 0.0) -> Dict[str, Any]:
        return self._avatar.motion(path, fps)

    def save(self, folder: str, *, overwrite: bool = False) -> None:
        """Write this avatar as a run folder that ``load_avatar`` and ``sfgs eval``, ``render`` and ``export`` take
        (the run's config, training records and fits files with these parameters; Adam's moments start afresh)."""
        self._avatar.save(folder, overwrite=overwrite)

    def set_cached(self, cached: bool) -> None:
        self._avatar.set_cached(cached)

    @property
    def device(self) -> torch.device:
        return torch.device(self._avatar.device)

    @property
    def frame_count(self) -> int:
        return self._avatar.frame_count

    @property
    def iteration(self) -> int:
        return self._avatar.iteration

    @property
    def expression_count(self) -> int:
        return self._avatar.expression_count

    @property
    def gaussian_count(self) -> int:
        return self._avatar.gaussian_count

    @property
    def config_yaml(self) -> str:
        return self._avatar.config_yaml

    @property
    def dataset_path(self) -> str:
        return self._avatar.dataset_path


def load_avatar(run: str, device: str = "cpu", data: str = "", other_dataset: bool = False) -> Avatar:
    """Load a trained avatar from a run folder (``sfgs train --out RUN``) as an ``nn.Module``; `data` points at its
    dataset if it moved (another dataset than the one it trained on only with ``other_dataset=True``)."""
    return Avatar(_C.load_avatar(run, device, data, other_dataset))
