"""sfgs.Avatar as a torch.nn.Module: its parameters are the avatar's, state_dict round-trips bit for bit, training
mode differentiates renders with respect to the parameters, batches equal single renders, and the training loss
is the trainer's. Uses conftest.py's tiny run (skipped without SFGS_EXECUTABLE)."""
import copy
import pickle

import pytest
import torch

import sfgs


def test_is_a_module_whose_parameters_are_the_checkpoints(run):
    avatar = sfgs.load_avatar(run)
    assert isinstance(avatar, torch.nn.Module) and not avatar.training
    names = [name for name, _ in avatar.named_parameters()]
    assert names and len(names) == len(set(names))
    assert any(name.startswith("feature_field.") for name in names)
    assert all(p.requires_grad and p.dtype == torch.float32 for p in avatar.parameters())
    assert any(name == "opacities" for name, _ in avatar.named_buffers())
    # The parameters are the avatar's own tensors: changing them in place changes the render, cached features too.
    avatar.set_cached(True)
    camera, pose = avatar.frame(9)["camera"], avatar.frame(9)["pose"]
    with torch.no_grad():
        before = avatar.render(camera, pose)["image"]
        for p in avatar.parameters():
            p.zero_()
        after = avatar.render(camera, pose)["image"]
    assert (before - after).abs().max() > 1e-3


def test_state_dict_round_trips_bit_for_bit(run):
    trained = sfgs.load_avatar(run)
    state = {k: v.clone() for k, v in trained.state_dict().items()}
    other = sfgs.load_avatar(run)
    with torch.no_grad():
        for p in other.parameters():
            p.add_(1.0)
    other.load_state_dict(state)
    for key, value in other.state_dict().items():
        assert torch.equal(value, state[key]), key
    frame = other.frame(9)
    with torch.no_grad():
        assert torch.equal(other.render(frame["camera"], frame["pose"])["image"],
                           trained.render(frame["camera"], frame["pose"])["image"])
    # Pickling (and copy.deepcopy) reload the run and then the state.
    copied = pickle.loads(pickle.dumps(other))
    for key, value in copied.state_dict().items():
        assert torch.equal(value, state[key]), key
    assert copy.deepcopy(other).gaussian_count == other.gaussian_count


def test_training_mode_differentiates_renders_with_respect_to_the_parameters(run):
    avatar = sfgs.load_avatar(run)
    frame = avatar.frame(0)
    assert avatar.train() is avatar and avatar.training
    avatar(frame["camera"], frame["pose"]).sum().backward()
    reached = [name for name, p in avatar.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0]
    assert any(name.startswith("feature_field.") for name in reached), reached
    avatar.eval()
    assert not avatar.training


def test_a_batch_equals_single_renders(run):
    avatar = sfgs.load_avatar(run)
    frames = [avatar.frame(i) for i in (0, 3, 9)]
    cameras, poses = [f["camera"] for f in frames], [f["pose"] for f in frames]
    with torch.no_grad():
        batch = avatar.render(cameras, poses)
        assert batch["image"].shape == (3, 32, 40, 3) and batch["radii"].shape[0] == 3
        for b, f in enumerate(frames):
            single = avatar.render(f["camera"], f["pose"])
            for key in ("image", "alpha", "depth", "radii", "visible"):
                assert torch.equal(batch[key][b], single[key]), key
        shared = avatar.render(cameras[0], poses)  # one camera for every pose
        assert torch.equal(shared["image"][2], avatar.render(cameras[0], poses[2])["image"])
    with pytest.raises(RuntimeError, match="3 cameras but 2 poses"):
        avatar.render(cameras, poses[:2])


def test_training_loss_is_the_trainers_and_fine_tunes(run):
    avatar = sfgs.load_avatar(run).train()
    frame = avatar.frame(0)
    target = avatar.render(frame["camera"], frame["pose"])["image"].detach().flip(1)  # a different image
    optimiser = torch.optim.Adam(avatar.parameters(), lr=1e-3)
    losses = []
    for _ in range(6):
        optimiser.zero_grad()
        terms = avatar.training_loss(frame["camera"], frame["pose"], target, lpips=False)
        terms["total"].backward()
        optimiser.step()
        losses.append(terms["total"].item())
    summed = ("image", "lab", "gradient", "mean_offset", "scale", "laplacian_mean", "laplacian_scale")
    assert set(summed) | {"l1", "ssim", "total", "render"} == set(terms)
    assert terms["total"].item() == pytest.approx(sum(terms[k].item() for k in summed), rel=1e-6)
    assert not terms["l1"].requires_grad and terms["total"].requires_grad
    assert losses[-1] < losses[0]


def test_to_device_and_bad_conversions(run):
    avatar = sfgs.load_avatar(run)
    assert avatar.to("cpu") is avatar and avatar.device == torch.device("cpu")
    with pytest.raises(TypeError, match="float32"):
        avatar.to(torch.float64)
    with pytest.raises(TypeError, match="only .to"):
        avatar.half()
    if not sfgs.cuda_available():
        with pytest.raises(RuntimeError, match="no CUDA backend"):
            avatar.to("cuda")


def test_to_cuda_moves_the_same_tensors_and_renders_as_an_avatar_loaded_there(run):
    if not (torch.cuda.is_available() and sfgs.cuda_available()):
        pytest.skip("moving to CUDA needs a GPU and a CUDA build")
    avatar = sfgs.load_avatar(run)
    frame = avatar.frame(9)
    before = dict(avatar.named_parameters())
    with torch.no_grad():
        on_cpu = avatar.render(frame["camera"], frame["pose"])["image"]
    assert avatar.to("cuda") is avatar and avatar.device.type == "cuda"
    assert all(p.is_cuda and before[name] is p for name, p in avatar.named_parameters()), "moved in place"
    with torch.no_grad():
        moved = avatar.render(frame["camera"], frame["pose"])["image"]
        loaded = sfgs.load_avatar(run, device="cuda").render(frame["camera"], frame["pose"])["image"]
    assert moved.is_cuda and (moved - loaded).abs().max().item() < 1e-5
    assert (moved.cpu() - on_cpu).abs().max().item() < 1e-3
    avatar.cpu()
    assert not any(p.is_cuda for p in avatar.parameters())
    with torch.no_grad():
        assert (avatar.render(frame["camera"], frame["pose"])["image"] - on_cpu).abs().max().item() < 1e-6


def test_renders_differentiate_the_camera_and_optimise_a_pose(run):
    avatar = sfgs.load_avatar(run)
    frame = avatar.frame(9)
    camera = dict(frame["camera"], world_to_camera=frame["camera"]["world_to_camera"].clone().requires_grad_(True))
    avatar.render(camera, frame["pose"])["image"].sum().backward()
    assert camera["world_to_camera"].grad is not None and camera["world_to_camera"].grad.abs().sum() > 0
    # A pose fitted to the image of another: the image error falls.
    with torch.no_grad():
        target = avatar.render(frame["camera"], frame["pose"])["image"]
    body_pose = (frame["pose"]["body_pose"].clone().float() + 0.2).requires_grad_(True)
    optimiser = torch.optim.Adam([body_pose], lr=0.02)
    errors = []
    for _ in range(8):
        optimiser.zero_grad()
        error = (avatar.render(frame["camera"], dict(frame["pose"], body_pose=body_pose))["image"] - target).abs().mean()
        error.backward()
        optimiser.step()
        errors.append(error.item())
    assert errors[-1] < errors[0]


def test_a_fine_tuned_avatar_saves_as_a_run_that_sfgs_eval_scores(run, tmp_path):
    import json
    import os
    import subprocess

    avatar = sfgs.load_avatar(run)
    with torch.no_grad():
        for p in avatar.parameters():
            p.mul_(0.9)
    folder = str(tmp_path / "tuned")
    avatar.save(folder)
    with pytest.raises(RuntimeError, match="exists; pass overwrite=True"):
        avatar.save(folder)
    avatar.save(folder, overwrite=True)
    reloaded = sfgs.load_avatar(folder)
    for (name, value), (_, saved) in zip(avatar.state_dict().items(), reloaded.state_dict().items()):
        assert torch.equal(value, saved), name
    frame = avatar.frame(9)
    with torch.no_grad():
        image = avatar.render(frame["camera"], frame["pose"])["image"]
    sfgs_executable = os.environ["SFGS_EXECUTABLE"]
    subprocess.run([sfgs_executable, "eval", "--run", folder, "--split", "test"], check=True,
                   capture_output=True)
    with open(os.path.join(folder, "metrics_test.json")) as f:
        reported = json.load(f)["per_frame"][0]["psnr"]
    data = sfgs.read_dataset(avatar.dataset_path).frame(9)
    expected = sfgs.evaluate(image, data["image"], data["eval_mask"], lpips=False)["psnr"]
    assert reported == pytest.approx(expected, abs=1e-6)
