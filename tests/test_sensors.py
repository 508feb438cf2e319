import pytest
import torch

from rawsim.color import camera_from_srgb
from rawsim.errors import ParameterError
from rawsim.isp.transfer import srgb_decode
from rawsim.pipelines.unprocess import STRIP_ROWS, unprocess_tensor
from rawsim.sensors import MonoSensor, RGBSensor, Sensor


@pytest.fixture
def sony():
    return RGBSensor.from_profile("sony_a7s2")


def test_unprocess_chain_matches_hand_computation(sony):
    params = sony.default_params(800, safe_white_balance=False)
    img = torch.rand(1, 3, 4, 6, generator=torch.Generator().manual_seed(0))
    cam = sony.unprocess(img, "rgb", params)
    a = torch.from_numpy(camera_from_srgb(params.xyz_to_camera)).float()
    expected = torch.einsum("ij,bjhw->bihw", a, srgb_decode(img))
    expected = expected / torch.tensor(params.wb_gains).float().view(1, 3, 1, 1)
    assert torch.allclose(cam, expected, atol=1e-6)
    dn = sony.linrgb2raw(cam, params)
    assert torch.allclose(dn, sony.cfa.mosaic(expected) * (16383 - 512) + 512, atol=1e-2)


def test_white_maps_to_white_level(sony):
    params = sony.default_params(100)
    dn = sony.linrgb2raw(sony.unprocess(torch.ones(1, 3, 2, 2), "rgb", params), params)
    # Sites of the green channel (gain 1) reach the white level exactly.
    g = sony.cfa.masks(2, 2)[1].bool()
    assert torch.allclose(dn[0, 0][g], torch.full((2,), 16383.0))


def test_simu_noise_rounds_and_saturates(sony):
    dn = torch.tensor([[[[400.0, 20000.0], [900.3, 16000.0]]]])
    out = sony.simu_noise(dn, 102400, key=1)
    assert torch.equal(out, out.round()) and out.min() >= 0 and out.max() <= 16383
    with pytest.raises(ParameterError, match="outside the range"):
        sony.simu_noise(dn, 204800)


def test_gradients_flow_through_the_inverse_isp(sony):
    params = sony.default_params(1600)
    img = torch.rand(1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    dn = sony.linrgb2raw(sony.unprocess(img, "rgb", params), params)
    noisy = sony.simu_noise(dn, 1600, key=0)
    noisy.sum().backward()
    assert img.grad is not None and bool((img.grad.abs() > 0).any())


def test_pack_round_trip_normalised(sony):
    dn = torch.randint(512, 16383, (2, 1, 6, 8)).float()
    planes = sony.bayer2rggb(dn)
    assert planes.shape == (2, 4, 3, 4)
    assert torch.allclose(sony.rggb2bayer(planes), dn, atol=1e-2)


def test_strip_pipeline_equals_stage_by_stage(sony):
    h = STRIP_ROWS + 6  # more than one strip, ragged last strip
    img = torch.randint(0, 256, (1, 3, h, 10), dtype=torch.uint8)
    params = sony.default_params(3200, vignetting=0.7, tone="smoothstep")
    noisy, clean = unprocess_tensor(sony, img, params, noise="none", clean=True)
    staged = sony.linrgb2raw(sony.unprocess(img.float() / 255, "rgb", params), params)
    assert torch.allclose(clean, staged.round().clamp(0, 16383), atol=1.0)
    assert torch.equal(noisy, clean)


def test_unprocess_tensor_is_deterministic_and_seed_dependent(sony):
    img = torch.rand(1, 3, 16, 16)
    params = sony.default_params(6400)
    a, _ = unprocess_tensor(sony, img, params, key=5)
    b, _ = unprocess_tensor(sony, img, params, key=5)
    c, _ = unprocess_tensor(sony, img, params, key=6)
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_unprocess_tensor_rejects_bad_input(sony):
    params = sony.default_params(100)
    with pytest.raises(ParameterError, match="even"):
        unprocess_tensor(sony, torch.rand(1, 3, 5, 4), params)
    with pytest.raises(ParameterError, match="NaN"):
        unprocess_tensor(sony, torch.full((1, 3, 4, 4), float("inf")), params)
    with pytest.raises(ParameterError, match="in_type"):
        sony.unprocess(torch.rand(1, 3, 2, 2), "srgb")


def test_base_and_mono_sensors():
    base = Sensor.from_config({"sensor_size": [24, 16], "sensor_res": [600, 400]})
    x = torch.rand(1, 3, 2, 2)
    assert torch.allclose(base.process(base.unprocess(x)), x, atol=1e-5)
    assert base.res == (600, 400)
    mono = MonoSensor(RGBSensor.from_profile("sony_a7s2").profile)
    grey = mono.unprocess(torch.full((1, 3, 2, 2), 0.5), "linear_rgb")
    assert grey.shape == (1, 1, 2, 2) and torch.allclose(grey, torch.full_like(grey, 0.5))
    dn = mono.linrgb2raw(grey)
    assert torch.allclose(mono.process(dn), torch.full_like(grey, 0.5 ** (1 / 2.2)), atol=1e-5)


def test_rgb_sensor_from_seed_config_and_spectral_response():
    config = {
        "bit": 12,
        "black_level": 256,
        "bayer_pattern": "grbg",
        "wavelengths": [450, 550, 650],
        "red_spectral_response": [0.0, 0.2, 1.0],
        "green_spectral_response": [0.2, 1.0, 0.3],
        "blue_spectral_response": [1.0, 0.2, 0.0],
    }
    s = RGBSensor.from_config(config)
    assert s.cfa.pattern == "GRBG" and s.white_level == 4095
    spectral = torch.ones(1, 3, 2, 2)
    rgb = s.response_curve(spectral)
    assert torch.allclose(rgb[0, :, 0, 0], torch.tensor([1.2, 1.5, 1.2]) / 1.5)


def test_integer_codes_must_fit_the_code_range(sony):
    params = sony.default_params(100)
    codes = torch.full((1, 3, 2, 2), 300, dtype=torch.int32)
    with pytest.raises(ParameterError, match=r"\[0, 255\]"):
        unprocess_tensor(sony, codes, params, code_max=255)
    ok, _ = unprocess_tensor(sony, codes, params, code_max=1023, noise="none")
    assert ok.shape == (1, 1, 2, 2)
