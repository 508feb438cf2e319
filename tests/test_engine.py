"""The compiled engine against the torch reference: the counter-based generator bit for
bit, the noise bit for bit, the fused unprocess kernel within one code value, for every
noise model, option (a lens too), CFA pattern, input kind, strip split and thread count."""

import json
from dataclasses import replace

import numpy as np
import pytest
import rawpy
import torch
from numba import njit
from scipy import stats

from rawsim.cameras.profiles import load_profile, profile_from_dict
from rawsim.cfa import CFA
from rawsim.engine.unprocess import (
    MODEL_CODES,
    add_noise_rows,
    dark_maps,
    noise_tables,
    noise_vector,
)
from rawsim.io.images import read_image
from rawsim.io.lensfun import lens_params
from rawsim.noise import kernels as eng
from rawsim.noise import reference as ref
from rawsim.noise.models import NOISE_MODELS, dark_draw, site_bias
from rawsim.noise.poisson_table import (
    BUCKETS,
    COUNT_BITS,
    LOW_BITS,
    POISSON_MEANS,
    UNIFORM_BITS,
    poisson_table,
    poisson_weights,
)
from rawsim.pipelines.unprocess import Simulation, UnprocessOptions, code_table, simulate
from rawsim.sensors import MonoSensor, RGBSensor, display_to_linear
from tests.conftest import DATA, installed_command_imports, numba_threads, thread_counts
from tests.test_dark_shading import dark_profile

KEY = ref.split_key(0x1234_5678_9ABC_DEF0)

# Random123's known-answer vectors for Philox4x32-10: (counter, key, output).
PHILOX_KAT = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    (
        (0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344),
        (0xA4093822, 0x299F31D0),
        (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1),
    ),
]


@pytest.mark.parametrize("counter,key,expected", PHILOX_KAT)
def test_philox_known_answers_in_both_backends(counter, key, expected):
    torch_words = ref.philox4x32(tuple(torch.tensor([c]) for c in counter), key)
    assert tuple(int(w) for w in torch_words) == expected
    numba_words = eng.philox4x32(*(np.uint64(c) for c in (*counter, *key)))
    assert tuple(int(w) for w in numba_words) == expected


@njit
def _engine_draws(lam, k0, k1, tukey, logistic, table):
    n = lam.shape[0]
    out = np.empty((5, n))
    for i in range(n):
        site = np.uint64(i) * np.uint64(7919) + np.uint64(2**40)  # beyond 32 bits too
        out[0, i] = eng.normal(site, eng.NORMAL, k0, k1)
        out[1, i] = eng.normal(site, eng.ROW, k0, k1)
        out[2, i] = eng.tukey_lambda(site, k0, k1, tukey)
        out[3, i] = eng.tukey_lambda(site, k0, k1, logistic)
        out[4, i] = eng.poisson(lam[i], site, k0, k1, table)
    return out


def test_draws_are_bit_equal_in_both_backends():
    n = 60_000
    lam = np.concatenate([np.geomspace(1e-3, 99.99, n - 4), [0.0, 1.0, 98.5, np.nextafter(100, 0)]])
    sites = torch.arange(n, dtype=torch.int64) * 7919 + 2**40
    tables = eng.tukey_table(0.14), eng.tukey_table(0.0)  # λ → 0: the logistic limit
    got = _engine_draws(lam, *eng.np_key(0x1234_5678_9ABC_DEF0), *tables, eng.poisson_words())
    expected = [
        ref.normal(sites, KEY),
        ref.normal(sites, KEY, "row"),
        ref.tukey_lambda(sites, KEY, ref.tukey_table(0.14)),
        ref.tukey_lambda(sites, KEY, ref.tukey_table(0.0)),
        ref.poisson(torch.from_numpy(lam), sites, KEY),
    ]
    for row, want in zip(got, expected, strict=True):
        assert np.array_equal(row, want.numpy())


@pytest.mark.parametrize("first,n", [(0, 31), (7, 30), (2**33 + 5, 17), (1, 1)])
def test_normal_rows_are_bit_equal_for_any_start_and_length(first, n):
    out = np.empty(n)
    eng.normal_row(np.uint64(first), *eng.np_key(0x1234_5678_9ABC_DEF0), out)
    sites = torch.arange(first, first + n, dtype=torch.int64)
    assert np.array_equal(out, ref.normal(sites, KEY).numpy())


@pytest.mark.parametrize("lam", [-0.5, -0.05, 0.0, 0.14, 1.0])
def test_tukey_tables_are_bit_equal_and_match_the_exact_quantile(lam):
    """The per-λ table of cubics is the same in both backends, and its quantiles are
    within 1e-11 (relative) of the exact formula, from the centre to the extreme
    uniforms 2⁻⁵³ and 1 − 2⁻⁵³."""
    table = eng.tukey_table(lam)
    assert np.array_equal(table, ref.tukey_table(lam).numpy())
    n = np.random.default_rng(3).integers(0, 2**52, 300_000)
    u = torch.from_numpy(np.concatenate([(n + 0.5) * 2.0**-52, [2**-53, 1 - 2**-53, 0.25]]))
    exact = ref.tukey_quantile(u, lam)
    got = ref.tukey_from_table(u, torch.from_numpy(table))
    assert torch.all((got - exact).abs() <= 1e-11 * exact.abs().clamp_min(1.0))
    assert np.array_equal(_engine_tukey(u.numpy(), table), got.numpy())


@njit
def _engine_tukey(u, table):
    return np.array([eng.tukey_from_table(v, table) for v in u])


@pytest.mark.parametrize("first,n", [(0, 31), (7, 30), (2**33 + 5, 17), (1, 1)])
def test_tukey_rows_are_bit_equal_and_tukey_distributed(first, n):
    table = eng.tukey_table(-0.1)
    out = np.empty(n)
    eng.tukey_lambda_row(np.uint64(first), *eng.np_key(0x1234_5678_9ABC_DEF0), table, out)
    sites = torch.arange(first, first + n, dtype=torch.int64)
    assert np.array_equal(out, ref.tukey_lambda(sites, KEY, torch.from_numpy(table)).numpy())
    big = np.empty(200_000)
    eng.tukey_lambda_row(np.uint64(first), *eng.np_key(17), table, big)
    for half in (big[0::2], big[1::2]):  # both uniforms of a block
        assert stats.kstest(half, "tukeylambda", args=(-0.1,)).pvalue > 1e-4


def test_normals_are_standard_and_pairs_independent():
    """Both Box–Muller branches: the even (cosine) and odd (sine) sites of a block are
    each N(0, 1), and uncorrelated with each other, also in their squares."""
    n = 400_000
    z = np.empty(n)
    eng.normal_row(np.uint64(0), *eng.np_key(17), z)
    for half in (z[0::2], z[1::2]):
        assert abs(half.mean()) < 5 / np.sqrt(half.size)
        assert abs(half.var() - 1) < 5 * np.sqrt(2 / half.size)
        assert stats.kstest(half, "norm").pvalue > 1e-4
    for a, b in ((z[0::2], z[1::2]), (z[0::2] ** 2, z[1::2] ** 2)):
        assert abs(np.corrcoef(a, b)[0, 1]) < 5 / np.sqrt(n / 2)


def test_exact_math_is_accurate():
    x = np.geomspace(1e-300, 1e300, 5001)
    assert np.allclose(ref.exact_log(torch.from_numpy(x)).numpy(), np.log(x), rtol=1e-15, atol=0)
    e = np.linspace(-700, 700, 5001)
    assert np.allclose(ref.exact_exp(torch.from_numpy(e)).numpy(), np.exp(e), rtol=1e-15, atol=0)
    u = torch.linspace(0, 1, 4001, dtype=torch.float64)[:-1]
    for sine, want in ((False, np.cos), (True, np.sin)):
        got = ref.exact_cos_sin_2pi(u, torch.full(u.shape, sine)).numpy()
        assert np.allclose(got, want(2 * np.pi * u.numpy()), atol=1e-15)


def _poisson_sample(lam, n, k0, k1):
    out = np.empty(n)
    sites = np.arange(n, dtype=np.uint64)
    eng.poisson_sites(np.full(n, lam), sites, k0, k1, eng.poisson_words(), out)
    return out


def test_poisson_alias_tables_hold_the_rounded_probabilities_exactly():
    table = poisson_table()
    assert table.shape == (POISSON_MEANS * BUCKETS,)
    low = (1 << LOW_BITS) - 1
    for m in range(POISSON_MEANS):
        first, weights = poisson_weights(m)
        assert sum(weights) == 2**UNIFORM_BITS
        # Each bucket of 2⁴⁴ uniform integers gives its own count below its
        # threshold and its alias above: summed, exactly the weights.
        got = np.zeros(1 << COUNT_BITS, np.int64)
        for j, word in enumerate(table[m * BUCKETS : (m + 1) * BUCKETS].tolist()):
            threshold, own = word & low, (word >> LOW_BITS) & 255
            assert own == (first + j if threshold else 0)  # bucket j's own count
            got[own] += threshold
            got[word >> (LOW_BITS + COUNT_BITS)] += (1 << LOW_BITS) - threshold
        assert not got[:first].any() and not got[first + len(weights) :].any()
        assert np.array_equal(got[first : first + len(weights)], weights)
        pmf = stats.poisson.pmf(np.arange(first, first + len(weights)), m)
        assert np.allclose(np.asarray(weights) / 2.0**UNIFORM_BITS, pmf, rtol=1e-12, atol=2.0**-52)
        # every count left out is negligible: below 2⁻⁵³ each, and 1e-15 together
        left_out = stats.poisson.cdf(first - 1, m) + stats.poisson.sf(first + len(weights) - 1, m)
        assert left_out < 1e-15


@pytest.mark.parametrize("lam", [0.0, 0.3, 1.0, 2.0, 9.9, 10.0, 37.5, 99.0, 99.99])
def test_poisson_is_exact_in_distribution(lam):
    n = 400_000
    x = _poisson_sample(lam, n, *eng.np_key(int(lam * 1000)))
    if lam == 0.0:
        assert not x.any()
        return
    assert np.all(x == np.floor(x)) and x.min() >= 0
    assert abs(x.mean() - lam) < 5 * np.sqrt(lam / n)
    assert abs(x.var() / lam - 1) < 5 * np.sqrt(2 / n) + 0.005
    # Every count with expected frequency ≥ 20, and the upper tail, by chi-square.
    edges = np.arange(0, int(lam + 12 * np.sqrt(lam) + 10))
    expected = n * stats.poisson.pmf(edges, lam)
    keep = expected >= 20
    counts = np.bincount(x.astype(int), minlength=edges.size)[: edges.size]
    observed = np.append(counts[keep], n - counts[keep].sum())
    want = np.append(expected[keep], n - expected[keep].sum())
    assert stats.chisquare(observed, want).pvalue > 1e-4
    for q in (1e-2, 1e-3):  # upper tails: counts within 4.5 σ of their expectation
        tail = stats.poisson.isf(q, lam)
        expected_count = n * stats.poisson.sf(tail, lam)
        assert abs(np.sum(x > tail) - expected_count) < 4.5 * np.sqrt(expected_count)


def _physics_profile(pattern: str):
    profile = load_profile("canon_eos_70d")
    noise = replace(profile.noise, channel_bias=(3.0, 1.0, -1.0, -2.0))
    return replace(profile, noise=noise, cfa=CFA(pattern))


@pytest.mark.parametrize("model", NOISE_MODELS)
def test_noise_is_bit_equal_for_any_strip_split(pattern, model):
    profile = _physics_profile(pattern)
    sensor = RGBSensor(profile)
    levels = sensor.noise_levels(1600 if model != "gaussian" else 800, model)
    rng = np.random.default_rng(1)
    dn = rng.uniform(profile.black_level - 20, profile.white_level * 0.3, (24, 30)).astype(
        np.float32
    )
    dn[:4] = profile.black_level + rng.uniform(0, 60, (4, 30))  # exact-Poisson counts
    whole = sensor.simu_noise(torch.from_numpy(dn)[None, None], 1600, levels, 99)[0, 0].numpy()
    for rows in (2, 6, 24):  # the reference in strips
        parts = [
            sensor.simu_noise(torch.from_numpy(dn[t : t + rows])[None, None], 1600, levels, 99, t)
            for t in range(0, 24, rows)
        ]
        assert np.array_equal(torch.cat(parts, 2)[0, 0].numpy(), whole)
    bias = site_bias(levels, profile.cfa, 0, 2, 2, "cpu")
    bias = np.zeros((2, 2)) + (0.0 if bias is None else bias.numpy())
    out = np.empty(dn.shape, np.uint16)
    p = noise_vector(levels, profile.black_level)
    for top in (0, 10):  # the engine's rows from 0, and from 10 on
        add_noise_rows(
            dn[top:],
            top,
            30,
            MODEL_CODES[model],
            p,
            *noise_tables(levels),
            *eng.np_key(99),
            bias,
            *dark_maps(levels, None),
            float(profile.white_level),
            out[top:],
        )
        assert np.array_equal(out, whole.astype(np.uint16))


@pytest.mark.parametrize("iso", [400, 3200])  # the test map's two gain ranges
def test_dark_terms_are_bit_equal_for_any_strip_split(pattern, iso, tmp_path):
    """Dark shading (a crop of the map) and the black-level offset: the reference in
    strips and the engine's rows give the same bits as the whole image."""
    base = load_profile(dark_profile(tmp_path, 42, 48))
    profile = replace(base, noise=replace(base.noise, channel_bias=(3.0, 1.0, -1.0, -2.0)))
    profile = replace(profile, cfa=CFA(pattern))
    sensor = RGBSensor(profile)
    levels = sensor.noise_levels(iso, "physics")
    rng = np.random.default_rng(2)
    dn = rng.uniform(profile.black_level - 20, profile.black_level + 900, (24, 30)).astype(
        np.float32
    )
    whole = sensor.simu_noise(torch.from_numpy(dn)[None, None], iso, levels, 99)[0, 0].numpy()
    plain = replace(levels, dark_shading=None, black_level_sigma=0.0)
    plain = sensor.simu_noise(torch.from_numpy(dn)[None, None], iso, plain, 99)[0, 0].numpy()
    assert np.abs(whole - plain).mean() > 1  # the dark terms are there
    for rows in (6, 12):
        parts = [
            sensor.simu_noise(
                torch.from_numpy(dn[t : t + rows])[None, None], iso, levels, 99, t, 24
            )
            for t in range(0, 24, rows)
        ]
        assert np.array_equal(torch.cat(parts, 2)[0, 0].numpy(), whole)
    draw = dark_draw(levels, 99, 24, 30, profile.cfa)
    assert draw.top % profile.cfa.period[0] == 0 and draw.left % profile.cfa.period[1] == 0
    bias = site_bias(levels, profile.cfa, 0, *profile.cfa.period, "cpu").numpy()
    out = np.empty(dn.shape, np.uint16)
    for top in (0, 12):
        add_noise_rows(
            dn[top:],
            top,
            30,
            MODEL_CODES["physics"],
            noise_vector(levels, profile.black_level, draw),
            *noise_tables(levels),
            *eng.np_key(99),
            bias,
            *dark_maps(levels, draw),
            float(profile.white_level),
            out[top:],
        )
        assert np.array_equal(out, whole.astype(np.uint16))


@pytest.mark.parametrize("model", ["poisson-gaussian", "physics"])
def test_the_engine_in_bands_gives_the_whole_images_bits(pattern, model):
    """An image unprocessed band by band as it is decoded (any rows, not whole CFA
    periods) gives the bits of the whole at once: CFA rows, shading, noise counters."""
    profile = _physics_profile(pattern)
    sensor = RGBSensor(profile)
    options = UnprocessOptions(profile=profile, iso=1600, noise=model, vignetting=0.8, clean=True)
    pixels = read_image(DATA / "srgb" / "coffee.png").pixels[100:164, 200:296]
    whole = simulate(sensor, pixels, options, 5, engine=True)
    for cuts in ([0, 7, 8, 40, 64], [0, 64]):
        bands = iter(zip(cuts[:-1], cuts[1:], strict=True))
        banded = simulate(sensor, pixels, options, 5, engine=True, bands=bands)
        assert torch.equal(banded.noisy, whole.noisy) and torch.equal(banded.clean, whole.clean)
    # the torch reference, and what the engine reads whole (floats), take every band first
    reference = simulate(sensor, pixels, options, 5, engine=False, bands=iter([(0, 30), (30, 64)]))
    assert torch.equal(reference.noisy, simulate(sensor, pixels, options, 5, engine=False).noisy)
    floats = pixels.astype(np.float32) / 255
    banded = simulate(sensor, floats, options, 5, engine=True, bands=iter([(0, 30), (30, 64)]))
    assert torch.equal(banded.noisy, simulate(sensor, floats, options, 5, engine=True).noisy)


PHOTO = read_image(DATA / "srgb" / "coffee.png").pixels[100:164, 200:296]
PHOTO16 = read_image(DATA / "srgb16" / "hdr_room_16bit.png").pixels[200:248, 300:372]
EXR = read_image(DATA / "exr" / "img2601_float_zip.exr").pixels[100:140, 100:160]

OPTIONS = [
    {},
    {"randomize": True},
    {"safe_white_balance": False, "exposure_ev": 1.5},
    {"vignetting": 0.8, "tone": "reinhard", "transfer": "gamma:2.2"},
    {"iso_range": (100, 12800), "iso": None},
    # a kit zoom at its widest: distortion, lateral CA and vignetting (--lens)
    {"lens": lens_params("Canon EF-S 18-55mm f/3.5-5.6 IS STM", 18.0, 3.5)[0], "vignetting": 0.5},
]


def _compare(sensor, pixels, options, display_referred=True, code_max=None):
    kw = {"display_referred": display_referred, "code_max": code_max}
    a = simulate(sensor, pixels, options, 5, engine=True, **kw)
    b = simulate(sensor, pixels, options, 5, engine=False, **kw)
    assert a.params == b.params and a.levels == b.levels
    clean_a, clean_b = (Simulation.codes(s.clean).astype(int) for s in (a, b))
    assert np.abs(clean_a - clean_b).max() <= 1  # float64 vs float32 stages
    assert np.mean(clean_a != clean_b) < 0.002
    # The noise is bit-equal for equal clean signals (test above); where the float32
    # and float64 signals round apart, or fall either side of the exact-Poisson
    # threshold, a site's draw differs. That stays as rare as the rounding.
    noisy_a, noisy_b = (Simulation.codes(s.noisy).astype(int) for s in (a, b))
    assert np.mean(noisy_a != noisy_b) < 0.002
    return a


@pytest.mark.parametrize("model", NOISE_MODELS)
@pytest.mark.parametrize("extra", OPTIONS, ids=lambda o: ",".join(o) or "default")
def test_engine_matches_reference(pattern, model, extra):
    profile = _physics_profile(pattern)
    options = UnprocessOptions(
        **({"profile": profile, "iso": 3200} | extra), noise=model, clean=True
    )
    _compare(RGBSensor(profile), PHOTO, options)


@pytest.mark.parametrize("model", ["poisson-gaussian", "physics"])
def test_engine_matches_reference_on_16_bit_float_mono_and_seed_matrix(model):
    profile = _physics_profile("GBRG")
    options = UnprocessOptions(profile=profile, iso=800, noise=model, clean=True)
    _compare(RGBSensor(profile), PHOTO16, options, code_max=65535)
    _compare(RGBSensor(profile), EXR, options, display_referred=False)
    _compare(MonoSensor(profile), PHOTO, replace(options, sensor="mono"))
    seed = {"bit": 12, "black_level": 64, "bayer_pattern": "bggr", "white_balance_d50": [2, 1, 1.8]}
    seed["color_matrix_d50"] = [
        [1.6, -0.4, -0.2],
        [-0.3, 1.5, -0.2],
        [0.0, -0.5, 1.5],
        [0.01, 0, 0.02],
    ]
    seed |= {"read_noise_std": 0.5, "shot_noise_std_alpha": 0.4}
    seeded = profile_from_dict(seed, "<seed>")
    _compare(RGBSensor(seeded), PHOTO, UnprocessOptions(profile=seeded, iso=400, clean=True))


DARK_OPTIONS = [{}, {"randomize": True}, {"iso_range": (100, 12800), "iso": None}]


@pytest.mark.parametrize("extra", DARK_OPTIONS, ids=lambda o: ",".join(o) or "default")
def test_engine_matches_reference_with_dark_shading(pattern, extra, tmp_path):
    profile = load_profile(dark_profile(tmp_path, 70, 102)).with_cfa(pattern)
    options = UnprocessOptions(
        **({"profile": profile, "iso": 3200} | extra), noise="physics", clean=True
    )
    a = _compare(RGBSensor(profile), PHOTO, options)
    assert a.levels.has_dark
    if not extra:
        _compare(MonoSensor(profile), PHOTO, replace(options, sensor="mono"))


@pytest.mark.parametrize("dark", [False, True], ids=["", "dark-shading"])
def test_engine_output_does_not_depend_on_threads(dark, tmp_path):
    profile = load_profile(dark_profile(tmp_path, 70, 100)) if dark else _physics_profile("RGGB")
    options = UnprocessOptions(profile=profile, iso=6400, noise="physics", clean=True)
    sensor = RGBSensor(profile)
    outputs = []
    for threads in thread_counts():
        with numba_threads(threads):
            outputs.append(Simulation.codes(simulate(sensor, PHOTO, options, 3, engine=True).noisy))
    assert np.array_equal(*outputs)


@pytest.mark.parametrize("tone", ["none", "smoothstep", "reinhard"])
@pytest.mark.parametrize("transfer", ["srgb", "bt2020", "romm", "linear", "gamma:2.2"])
def test_code_table_is_the_display_decode_rounded_once(tone, transfer):
    """Integer inputs read through one float32 table: the torch decode of code / top
    in float64, rounded once (the NumPy path for the toe curves gives the same bits)."""
    for top in (255, 65535):
        codes = torch.arange(top + 1, dtype=torch.float64) / top
        expected = display_to_linear(codes, tone, transfer).float().numpy()
        table = code_table(top, tone, transfer)
        assert table.dtype == np.float32 and np.array_equal(table, expected)


def test_one_file_unprocess_imports_no_torch(tmp_path):
    """The installed command unprocesses an 8-bit photo on the engine without importing
    torch (a second of a one-file run) or numba's BLAS probe (``scipy.linalg``). Its
    DNG holds the mosaic that :func:`simulate` gives with the torch sensor object:
    the torch-free :class:`SensorLayout` stands for it exactly."""
    out = tmp_path / "out"
    photo = DATA / "srgb" / "chelsea.png"
    args = ("-q", "unprocess", photo, "-o", out, "-p", "sony_a7s2", "--iso", "3200", "--seed", "4")
    imported = installed_command_imports(*args)
    assert "rawsim.engine.unprocess" in imported
    assert "torch" not in imported and "scipy.linalg" not in imported
    sidecar = json.loads((out / "chelsea.json").read_text())
    options = UnprocessOptions(profile=load_profile("sony_a7s2"), iso=3200)
    pixels = read_image(photo).pixels
    expected = simulate(RGBSensor(options.profile), pixels, options, sidecar["file_seed"])
    with rawpy.imread(str(out / "chelsea.dng")) as raw:
        assert np.array_equal(raw.raw_image_visible, Simulation.codes(expected.noisy))
