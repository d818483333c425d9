"""sfgs: structure-aware fine-grained Gaussian splatting for animatable full-body avatars (C++/LibTorch core)."""
import torch  # noqa: F401  (loads libtorch and its Python bindings before the extension)

from ._C import (  # noqa: F401
    LOW_PASS_VARIANCE_PX2,
    MAX_ALPHA,
    MIN_ALPHA,
    MIN_TRANSMITTANCE,
    TILE_SIZE,
    Dataset,
    Mano,
    Smplx,
    camera_in_front,
    cuda_available,
    demo_scene,
    evaluate,
    look_at_camera,
    lpips,
    orbit_camera,
    psnr,
    read_dataset,
    read_motion,
    render,
    ssim,
)
from .avatar import Avatar, load_avatar  # noqa: F401

__all__ = ["render", "cuda_available", "demo_scene", "load_avatar", "read_motion", "read_dataset", "psnr", "ssim",
           "lpips", "evaluate", "look_at_camera", "camera_in_front", "orbit_camera", "Avatar", "Dataset", "Smplx",
           "Mano"]
