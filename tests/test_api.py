"""Python API: batch unprocess ≡ the files job, gradients, process, Dataset, example."""

import numpy as np
import pytest
import rawpy
import torch
from click.testing import CliRunner
from torch.utils.data import DataLoader

import rawsim
from rawsim.errors import ParameterError
from rawsim.io.images import read_image
from rawsim_cli.main import cli
from tests.conftest import DATA, ROOT


@pytest.fixture(scope="module")
def sensor():
    return rawsim.RGBSensor.from_profile("canon_eos_70d")


def _codes(name):
    decoded = read_image(DATA / "srgb" / name)
    return torch.from_numpy(decoded.pixels).permute(2, 0, 1)[None].to(torch.int32), decoded


@pytest.mark.parametrize("mono", [False, True])
def test_batch_unprocess_matches_the_files_job_bit_for_bit(sensor, tmp_path, mono):
    names = ["chelsea.png", "rocket.jpg"]
    args = ["unprocess", *(DATA / "srgb" / n for n in names), "-o", tmp_path, "--seed", 11]
    args += ["--profile", "canon_eos_70d", "--iso-range", 200, 6400, "--randomize"]
    args += ["--noise", "physics", "--clean", "--sensor", "mono" if mono else "rgb"]
    r = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    images = [_codes(n) for n in names]
    # rocket.jpg is 427×640: the files job crops odd sizes to even, so compare like for like
    h = min(im.shape[-2] for im, _ in images)
    w = min(im.shape[-1] for im, _ in images)
    dev = rawsim.MonoSensor(sensor.profile) if mono else sensor
    for (image, decoded), name in zip(images, names, strict=True):
        assert decoded.code_max == 255
        seeds = [rawsim.file_seed(11, name)]
        noisy, clean, meta = rawsim.unprocess(
            image, dev, seeds, iso_range=(200, 6400), randomize=True, noise="physics", code_max=255
        )
        stem = name.rsplit(".", 1)[0]
        for kind, got in (("dng", noisy), ("clean.dng", clean)):
            with rawpy.imread(str(tmp_path / f"{stem}.{kind}")) as raw:
                ref = raw.raw_image.copy()
            assert np.array_equal(got[0, 0].numpy().astype(np.uint16), ref)
        assert meta[0]["iso"] == pytest.approx(
            rawpy.imread(str(tmp_path / f"{stem}.dng")).other.iso_speed, abs=0.5
        )
    # a batch is the samples one by one, in any order
    crop = torch.cat([im[..., :h, :w] for im, _ in images])
    seeds = [5, 9]
    kw = {"noise": "physics", "code_max": 255}
    both, _, meta = rawsim.unprocess(crop, dev, seeds, iso=[400, 3200], **kw)
    one, _, _ = rawsim.unprocess(crop[1:], dev, seeds[1:], iso=3200, **kw)
    assert torch.equal(both[1:], one) and [m["iso"] for m in meta] == [400, 3200]


@pytest.mark.parametrize("dtype", ["uint8", "uint16", "int32", "float32"])
def test_unprocess_reads_any_layout_as_the_files_job_does(sensor, dtype):
    """Channels-first, channels-last (strided) and cropped (non-contiguous) batches
    give the bits of the files job's call on each image's contiguous (H, W, 3)
    pixels, for each input type the API takes."""
    from rawsim.pipelines.unprocess import Simulation, UnprocessOptions, simulate

    decoded = read_image(DATA / "srgb" / "chelsea.png")
    codes = torch.from_numpy(decoded.pixels[:68, :100]).permute(2, 0, 1)[None]
    codes = torch.cat([codes, codes.flip(-1)])  # two samples: each writes its own slice
    code_max = {"uint8": None, "uint16": 65535, "int32": 255, "float32": None}[dtype]
    if dtype == "uint16":
        batch = (codes.to(torch.int32) * 257).to(torch.uint16)
    elif dtype == "float32":
        batch = codes.float() / 255
    else:
        batch = codes.to(getattr(torch, dtype))
    crop = batch[..., 2:66, 4:100]
    layouts = {
        "channels-first": crop.contiguous(),
        "channels-last": crop.permute(0, 2, 3, 1).contiguous().permute(0, 3, 1, 2),
        "crop": crop,
    }
    assert not layouts["crop"].is_contiguous() and not layouts["channels-last"].is_contiguous()
    seeds, kw = [21, 22], {"iso": 3200, "noise": "physics", "code_max": code_max}
    options = UnprocessOptions(profile=sensor.profile, iso=3200, noise="physics", clean=True)
    files = []
    for i, seed in enumerate(seeds):  # as unprocess_file: a decoded, contiguous (H, W, 3) array
        pixels = np.ascontiguousarray(crop[i].permute(1, 2, 0).numpy())
        sim = simulate(sensor, pixels, options, seed, code_max=code_max)
        files.append((Simulation.codes(sim.noisy), Simulation.codes(sim.clean)))
    buffers = (torch.full((2, 1, 64, 96), -1.0), torch.full((2, 1, 64, 96), -1.0))
    for name, images in layouts.items():
        noisy, clean, _ = rawsim.unprocess(images, sensor, seeds, **kw)
        assert noisy.shape == clean.shape == (2, 1, 64, 96) and noisy.dtype == torch.float32
        for i, (noisy_ref, clean_ref) in enumerate(files):
            assert np.array_equal(noisy[i, 0].numpy().astype(np.uint16), noisy_ref), name
            assert np.array_equal(clean[i, 0].numpy().astype(np.uint16), clean_ref), name
        assert noisy.equal(noisy.round()) and not noisy.equal(clean)
        into = rawsim.unprocess(images, sensor, seeds, **kw, out=buffers)
        assert into[0] is buffers[0] and into[1] is buffers[1]
        assert torch.equal(into[0], noisy) and torch.equal(into[1], clean)


def test_gradients_flow_through_unprocess_and_process(sensor):
    image, _ = _codes("chelsea.png")
    x = (image[..., :64, :96].float() / 255).requires_grad_()
    noisy, clean, meta = rawsim.unprocess(x, sensor, [1], iso=1600)
    assert noisy.requires_grad and clean.requires_grad
    rgb = rawsim.process(noisy, sensor, meta, demosaic="bilinear")
    assert rgb.shape == (1, 3, 64, 96)
    rgb.mean().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    with torch.no_grad():
        ref, _, _ = rawsim.unprocess(x, sensor, [1], iso=1600)
    assert torch.equal(noisy.detach(), ref)  # the same capture, bit for bit


def test_process_inverts_unprocess_on_clean_data(sensor):
    yy, xx = torch.meshgrid(torch.linspace(0, 1, 64), torch.linspace(0, 1, 64), indexing="ij")
    x = torch.stack([0.2 + 0.6 * xx, 0.3 + 0.4 * yy, 0.7 - 0.5 * xx * yy])[None]
    _, clean, meta = rawsim.unprocess(x, sensor, [0], iso=100, noise="none")
    with torch.no_grad():
        back = rawsim.process(clean, sensor, meta, tone="none")
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))
    assert torch.mean((back[inner] - x[inner]) ** 2) < 1e-4


@pytest.mark.parametrize(
    "changes",
    [{}, {"demosaic": "bilinear"}, {"demosaic": "menon", "tone": "reinhard"}, {"exposure": 3.0}],
    ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items()) or "default",
)
def test_process_without_gradients_runs_the_engine_as_the_reference(sensor, monkeypatch, changes):
    """No-grad CPU renders come from the compiled engine (the exact tail curves applied
    after it, values above 1 included); they agree with the torch reference."""
    from rawsim.pipelines import process as pipeline

    image, _ = _codes("chelsea.png")
    noisy, _, meta = rawsim.unprocess(image[..., :48, :64], sensor, [3], iso=800, code_max=255)
    calls = []
    monkeypatch.setattr(pipeline, "engine_render", _counted(pipeline.engine_render, calls))
    with torch.no_grad():
        ours = rawsim.process(noisy, sensor, meta, **({"exposure": 2.0} | changes))
    assert len(calls) == 1 and ours.shape == (1, 3, 48, 64) and ours.dtype == torch.float32
    assert float(ours.max()) > 1.0  # unclipped: the curves hold beyond white
    monkeypatch.setenv("RAWSIM_ENGINE", "0")
    with torch.no_grad():
        ref = rawsim.process(noisy, sensor, meta, **({"exposure": 2.0} | changes))
    assert len(calls) == 1
    assert torch.allclose(ours, ref, rtol=0, atol=1e-5), float((ours - ref).abs().max())


def test_process_takes_codes_only_from_whole_dn_in_range():
    """The engine's codes come from mosaics of whole DN in [0, 65535] only; any other
    value (a fraction, below 0, above 65535, NaN) sends the mosaic to the reference."""
    from rawsim.api import _codes

    m = torch.tensor([[0.0, 1.0], [65535.0, 512.0]])
    assert np.array_equal(_codes(m), m.numpy().astype(np.uint16))
    assert _codes(m.double()) is not None and _codes(m[:, :1]) is not None  # any dtype, strides
    for bad in (0.5, -1.0, 65536.0, 1e9, float("nan"), float("inf")):
        assert _codes(torch.where(m == 512, bad, m)) is None, bad


def _counted(fn, calls):
    def wrapper(*args, **kw):
        calls.append(1)
        return fn(*args, **kw)

    return wrapper


def test_api_errors(sensor):
    x = torch.rand(2, 3, 8, 8)
    with pytest.raises(ParameterError, match="one seed per image"):
        rawsim.unprocess(x, sensor, [1], iso=100)
    with pytest.raises(ParameterError, match="one ISO per image"):
        rawsim.unprocess(x, sensor, [1, 2], iso=[100])
    with pytest.raises(ParameterError, match="code_max"):
        rawsim.unprocess((x * 255).to(torch.int32), sensor, [1, 2], iso=100)
    with pytest.raises(ParameterError, match="out must be two float32 tensors"):
        rawsim.unprocess(x, sensor, [1, 2], iso=100, out=(torch.empty(2, 1, 8, 8),) * 1)
    with pytest.raises(ParameterError, match="out must be two float32 tensors"):
        rawsim.unprocess(x, sensor, [1, 2], iso=100, out=(torch.empty(2, 1, 8, 6),) * 2)
    with pytest.raises(ParameterError, match="without gradients"):
        rawsim.unprocess(x.clone().requires_grad_(), sensor, [1, 2], iso=100, out=(x[:, :1],) * 2)
    codes = (x * 1023).to(torch.int32)
    codes[1, 0, 3, 3] = 1024  # over a 10-bit code_max, whatever the type could hold
    for image in (codes, codes.to(torch.uint16)):
        with pytest.raises(ParameterError, match=r"must lie in \[0, 1023\]"):
            rawsim.unprocess(image, sensor, [1, 2], iso=100, code_max=1023)


def _batches(dataset, workers):
    loader = DataLoader(dataset, batch_size=2, num_workers=workers)
    return [b for b in loader]


def test_dataset_is_deterministic_across_workers_and_epochs(sensor):
    data = rawsim.UnprocessDataset(DATA / "srgb", sensor, crop=64, seed=3, noise="physics")
    assert len(data) == 4
    item = data[1]
    assert item["noisy"].shape == item["clean"].shape == (4, 32, 32)
    assert 0 <= float(item["clean"].min()) and float(item["clean"].max()) <= 1
    lo, hi = sensor.profile.iso_range
    assert lo <= float(item["iso"]) <= hi and float(item["gain"]) > 0
    serial, parallel = _batches(data, 0), _batches(data, 2)
    for a, b in zip(serial, parallel, strict=True):
        assert torch.equal(a["noisy"], b["noisy"]) and torch.equal(a["iso"], b["iso"])
    data.set_epoch(1)
    assert not torch.equal(data[1]["noisy"], item["noisy"])
    data.set_epoch(0)
    assert torch.equal(data[1]["noisy"], item["noisy"])
    mosaic = rawsim.UnprocessDataset(DATA / "srgb", sensor, crop=64, seed=3, layout="mosaic")
    assert mosaic[0]["noisy"].shape == (1, 64, 64)
    with pytest.raises(ParameterError, match="even"):
        rawsim.UnprocessDataset(DATA / "srgb", sensor, crop=63)


@pytest.mark.slow
def test_example_training_script_denoises_held_out_crops():
    """The README's example, shorter: on crops of a photo it never trains on, the
    denoised planes are closer to the clean ones than the noisy input (the full
    2000 steps give +3.6 dB at ISO 3200 in 2.6 minutes on 2 cores)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("train", ROOT / "examples" / "train_denoiser.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    result = module.main(["--steps", "250", "--valid-crops", "4"])
    assert len(result["losses"]) == 250 and all(np.isfinite(result["losses"]))
    assert result["denoised_psnr"] >= result["noisy_psnr"] + 0.4, result
