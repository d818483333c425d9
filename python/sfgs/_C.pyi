"""Type stubs of the compiled module sfgs._C (python/bindings*.cpp), re-exported by `import sfgs`; docs/python.md is
the reference. tests/python/test_stubs.py checks that every public name and every parameter name here matches the
module."""
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import torch

Tensor = torch.Tensor
# Tensors, or what torch.as_tensor takes (nested lists, numpy arrays).
TensorLike = Union[Tensor, Sequence[Any], Any]
# {'world_to_camera' (4, 4), 'fx', 'fy', 'cx', 'cy', 'width', 'height'}: Avatar.frame(i)["camera"] gives one.
CameraDict = Dict[str, Any]
# SMPL-X fields by name (global_orient, body_pose, jaw_pose, leye_pose, reye_pose, left_hand_pose, right_hand_pose,
# expression, transl) and 'time' (in [-1, 1], or None for a new motion); missing keys are at rest.
PoseDict = Dict[str, Any]

LOW_PASS_VARIANCE_PX2: float
MAX_ALPHA: float
MIN_ALPHA: float
MIN_TRANSMITTANCE: float
TILE_SIZE: int

def render(
    means: TensorLike,
    opacities: TensorLike,
    features: TensorLike,
    background: TensorLike,
    world_to_camera: TensorLike,
    fx: Union[float, Tensor],
    fy: Union[float, Tensor],
    cx: Union[float, Tensor],
    cy: Union[float, Tensor],
    width: int,
    height: int,
    *,
    scales: Optional[TensorLike] = None,
    rotations: Optional[TensorLike] = None,
    covariances: Optional[TensorLike] = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    low_pass: bool = True,
    antialiased: bool = False,
    deterministic: bool = False,
) -> Dict[str, Tensor]:
    """{'image' (H, W, C), 'alpha' (H, W), 'depth' (H, W), 'radii' (N, 2) int32, 'visible' (N) bool}."""

def cuda_available() -> bool: ...
def demo_scene(
    count: int = 20000, width: int = 320, height: int = 240, seed: int = 7, double_precision: bool = False
) -> Dict[str, Any]: ...
def load_avatar(run: str, device: str = "cpu", data: str = "", other_dataset: bool = False) -> Avatar: ...
def read_motion(path: str, fps: float = 0.0) -> Dict[str, Any]:
    """{'frames': [PoseDict, ...], 'fps', 'format', 'note', 'absolute_hands'}."""

def read_dataset(folder: str) -> Dataset: ...
def psnr(prediction: TensorLike, target: TensorLike) -> Tensor: ...
def ssim(prediction: TensorLike, target: TensorLike, border: str = "reflect") -> Tensor: ...
def lpips(prediction: TensorLike, target: TensorLike, net: str = "alex", weights_dir: str = "") -> Tensor: ...
def evaluate(
    prediction: TensorLike,
    image: TensorLike,
    mask: Optional[TensorLike] = None,
    *,
    eight_bit: bool = False,
    lpips: bool = True,
    weights_dir: str = "",
) -> Dict[str, Optional[float]]:
    """{'psnr', 'ssim', 'lpips'} of one frame as `sfgs eval` scores it."""

def look_at_camera(
    eye: Sequence[float], target: Sequence[float], width: int, height: int, fx: Optional[float] = None
) -> CameraDict: ...
def camera_in_front(
    target: Sequence[float],
    width: int,
    height: int,
    distance: float = 2.8,
    height_above: float = 0.0,
    angle: float = 0.0,
    fx: Optional[float] = None,
) -> CameraDict: ...
def orbit_camera(camera: CameraDict, centre: Sequence[float], angle: float) -> CameraDict: ...

class Avatar:
    def __init__(self, run: str, device: str = "cpu", data: str = "", other_dataset: bool = False) -> None: ...
    def gaussians(self, pose: PoseDict = {}) -> Dict[str, Tensor]: ...
    def render(
        self,
        camera: Union[CameraDict, List[CameraDict]],
        pose: Union[PoseDict, List[PoseDict]] = {},
        background: Optional[TensorLike] = None,
    ) -> Dict[str, Tensor]: ...
    def training_loss(
        self,
        camera: CameraDict,
        pose: PoseDict,
        image: TensorLike,
        *,
        mask: Optional[TensorLike] = None,
        background: Optional[TensorLike] = None,
        lpips: bool = True,
    ) -> Dict[str, Tensor]: ...
    def named_tensors(self, parameters: bool) -> List[Tuple[str, Tensor]]: ...
    def set_training(self, training: bool) -> None: ...
    def move_to(self, device: str) -> None: ...
    def centre(self, pose: PoseDict = {}) -> List[float]:
        """(x, y, z) of the posed body's bounding box centre."""

    def frame(self, index: int) -> Dict[str, Any]:
        """{'pose': PoseDict, 'camera': CameraDict, 'split': 'train' | 'val' | 'test'}."""

    def motion(self, path: str, fps: float = 0.0) -> Dict[str, Any]: ...
    def save(self, folder: str, *, overwrite: bool = False) -> None: ...
    def set_cached(self, cached: bool) -> None: ...
    @property
    def frame_count(self) -> int: ...
    @property
    def iteration(self) -> int: ...
    @property
    def expression_count(self) -> int: ...
    @property
    def gaussian_count(self) -> int: ...
    @property
    def config_yaml(self) -> str: ...
    @property
    def dataset_path(self) -> str: ...
    @property
    def training(self) -> bool: ...
    @property
    def device(self) -> str: ...
    @property
    def run(self) -> str: ...
    @property
    def data(self) -> str: ...
    @property
    def other_dataset(self) -> bool: ...

class Dataset:
    def __len__(self) -> int: ...
    def frame(self, index: int) -> Dict[str, Any]:
        """{'image' (H, W, 3), 'mask', 'eval_mask' (H, W), 'pose', 'camera', 'name', 'split'}."""

    def split(self, name: str) -> List[int]: ...
    @property
    def betas(self) -> Tensor: ...
    @property
    def format(self) -> str: ...
    @property
    def source(self) -> str: ...

class Smplx:
    def __init__(
        self,
        path: str,
        num_betas: int = 10,
        num_expression_coeffs: int = 10,
        use_pca: bool = False,
        flat_hand_mean: bool = False,
        device: str = "cpu",
        dtype: str = "float32",
    ) -> None: ...
    def forward(self, inputs: Dict[str, Tensor]) -> Dict[str, Tensor]: ...
    def __call__(self, inputs: Dict[str, Tensor]) -> Dict[str, Tensor]: ...
    @property
    def vertex_count(self) -> int: ...

class Mano:
    def __init__(
        self,
        path: str,
        num_betas: int = 10,
        use_pca: bool = False,
        num_pca_comps: int = 6,
        flat_hand_mean: bool = False,
        device: str = "cpu",
        dtype: str = "float32",
    ) -> None: ...
    def forward(self, inputs: Dict[str, Tensor]) -> Dict[str, Tensor]: ...
    def __call__(self, inputs: Dict[str, Tensor]) -> Dict[str, Tensor]: ...
