"""Output colour spaces: the matrices against the standards, the transfers (both
backends, gradients), the ICC profiles as LittleCMS (Pillow's ImageCms, transicc,
tificc) and exiftool read them, the tags of every format, and renders of a real raw
converted back to sRGB by a colour-managed reader."""

import hashlib
import io
import math
import struct
import subprocess
import zlib
from types import SimpleNamespace

import numpy as np
import OpenImageIO as oiio
import pytest
import tifffile
import torch
from click.testing import CliRunner
from PIL import Image, ImageCms

from rawsim.color import SRGB_TO_XYZ, XYZ_D50, XYZ_D65, chromatic_adaptation, srgb_from_camera
from rawsim.colorspaces import (
    ADOBE_RGB_GAMMA,
    BT2020_CURVE,
    OUTPUT_SPACES,
    RGB_SPACES,
    ROMM_CURVE,
    SRGB_CURVE,
    Encoding,
    TransferSpec,
    space_from_srgb,
    space_transfer,
)
from rawsim.errors import ParameterError
from rawsim.io.icc import PROFILE_DATE, colorants, icc_profile
from rawsim.io.images import write_image
from rawsim.isp.config import ColorMatrixStage, IspConfig, TransferStage
from rawsim.isp.transfer import apply_transfer, invert_transfer
from rawsim_cli.main import cli
from tests.conftest import DATA, psnr, require_tool

RAW = DATA / "raw" / "canon_eos60d_mlv.dng"
SPACES = tuple(RGB_SPACES)
TAGGED = (*SPACES, "xyz")

#: Linear RGB → XYZ (own white) as the standards print them: IEC 61966-2-1:1999
#: (sRGB, 5.2); SMPTE EG 432-1:2010 (P3-D65); Adobe RGB (1998) Color Image Encoding
#: 2005-05, 4.3.4.3; ITU-R BT.2087-0 (BT.2020, Annex 1); ISO 22028-2 (ROMM RGB, 5.2).
#: They derive D65 from xy (0.3127, 0.3290) and round to 4–5 decimals; rawsim's D65 is
#: ASTM E308's (see rawsim.colorspaces): they differ by up to 3e-4.
PUBLISHED = {
    "srgb": [[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]],
    "display-p3": [[0.4866, 0.2657, 0.1982], [0.2290, 0.6917, 0.0793], [0.0, 0.0451, 1.0439]],
    "adobe-rgb": [
        [0.57667, 0.18556, 0.18823],
        [0.29734, 0.62736, 0.07529],
        [0.02703, 0.07069, 0.99134],
    ],
    "rec2020": [[0.6370, 0.1446, 0.1689], [0.2627, 0.6780, 0.0593], [0.0, 0.0281, 1.0610]],
    "prophoto": [[0.7977, 0.1352, 0.0313], [0.2880, 0.7119, 0.0001], [0.0, 0.0, 0.8249]],
    # SMPTE ST 2065-1:2012 4.1.6 (AP0), Academy S-2014-004 4.1 (AP1): 10 decimals
    "aces2065-1": [
        [0.9525523959, 0.0, 0.0000936786],
        [0.3439664498, 0.7281660966, -0.0721325464],
        [0.0, 0.0, 1.0088251844],
    ],
    "acescg": [
        [0.6624541811, 0.1340042065, 0.1561876870],
        [0.2722287168, 0.6740817658, 0.0536895174],
        [-0.0055746495, 0.0040607335, 1.0103391003],
    ],
}
#: D50-adapted colorants (columns rXYZ, gXYZ, bXYZ) of the profiles others ship, as
#: Skia's SkNamedGamut lists them (sRGB, Display P3, Adobe RGB, Rec. 2020, from the
#: ICC, Apple and Adobe profiles); ProPhoto's are ROMM's own D50 matrix.
PROFILE_COLORANTS = {
    "srgb": [
        [0.436066, 0.385147, 0.143066],
        [0.222488, 0.716873, 0.060608],
        [0.013916, 0.097076, 0.714096],
    ],  # noqa: E501
    "display-p3": [
        [0.515102, 0.291965, 0.157153],
        [0.241182, 0.692236, 0.066582],
        [-0.001049, 0.041882, 0.784378],
    ],  # noqa: E501
    "adobe-rgb": [
        [0.60974, 0.20528, 0.14919],
        [0.31111, 0.62567, 0.06322],
        [0.01947, 0.06087, 0.74457],
    ],  # noqa: E501
    "rec2020": [
        [0.673459, 0.165661, 0.125100],
        [0.279033, 0.675338, 0.045629],
        [-0.001931, 0.029979, 0.797162],
    ],  # noqa: E501
    "prophoto": PUBLISHED["prophoto"],
}


# ------------------------------------------------------------------ matrices
@pytest.mark.parametrize("space", SPACES)
def test_matrix_against_the_standard(space):
    m = RGB_SPACES[space].to_xyz
    assert np.abs(m - PUBLISHED[space]).max() < 5e-4
    assert np.allclose(m.sum(axis=1), RGB_SPACES[space].white, atol=1e-12)


@pytest.mark.parametrize("space", SPACES)
def test_profile_colorants_against_published_profiles(space):
    """Against the profiles others ship; for ACES's spaces, which none in that list
    covers, against colour-science's matrices adapted to D50 by its Bradford."""
    chad, m = colorants(Encoding(space, "linear"))
    if space in PROFILE_COLORANTS:
        want = np.asarray(PROFILE_COLORANTS[space])
    else:
        import colour

        cs = colour.RGB_COLOURSPACES[{"aces2065-1": "ACES2065-1", "acescg": "ACEScg"}[space]]
        cat = colour.adaptation.matrix_chromatic_adaptation_VonKries(
            colour.xy_to_XYZ(cs.whitepoint), XYZ_D50, transform="Bradford"
        )
        want = cat @ cs.matrix_RGB_to_XYZ
    assert np.abs(m - want).max() < 5e-4
    assert np.allclose(chad @ RGB_SPACES[space].white, XYZ_D50, atol=1e-12)


def test_bradford_against_the_published_matrix():
    """Lindbloom's D65 → D50 Bradford matrix, for his whites (ASTM E308)."""
    d65, d50 = [0.95047, 1.0, 1.08883], [0.96422, 1.0, 0.82521]
    published = [
        [1.0478112, 0.0228866, -0.0501270],
        [0.0295424, 0.9904844, -0.0170491],
        [-0.0092345, 0.0150436, 0.7521316],
    ]
    assert np.abs(chromatic_adaptation(d65, d50) - published).max() < 1e-6
    assert np.allclose(chromatic_adaptation(d65, d65), np.eye(3), atol=1e-15)


@pytest.mark.parametrize("space", OUTPUT_SPACES)
def test_camera_matrix_goes_through_xyz(space):
    """Camera → output is camera → linear sRGB (as LibRaw) → XYZ (D65) → the space,
    Bradford-adapted to D50 for ProPhoto; camera white (after white balance) is
    white (1, 1, 1) in every RGB space."""
    xyz_to_camera = [
        [0.6461, -0.0907, -0.0882],
        [-0.4300, 1.2184, 0.2378],
        [-0.0819, 0.1944, 0.5931],
    ]
    raw = SimpleNamespace(xyz_to_camera=np.array(xyz_to_camera), camera_to_srgb=None)
    m = ColorMatrixStage(output_space=space).matrix(raw)
    to_srgb = srgb_from_camera(xyz_to_camera)
    if space == "camera":
        assert np.array_equal(m, np.eye(3))
        return
    if space == "srgb":
        assert np.array_equal(m, to_srgb)  # exactly today's matrix: sRGB renders unchanged
    xyz = SRGB_TO_XYZ @ to_srgb  # camera → XYZ (D65)
    if space == "xyz":
        assert np.allclose(m, xyz, atol=1e-12)
        return
    rgb = RGB_SPACES[space]
    adapted = chromatic_adaptation(XYZ_D65, rgb.white) @ xyz
    assert np.allclose(rgb.to_xyz @ m, adapted, atol=1e-12)
    assert np.allclose(m @ np.ones(3), 1.0, atol=1e-12)


# ------------------------------------------------------------------ transfers
def _bt2020(x):  # ITU-R BT.2020-2 Table 4, written out
    a, b = 1.09929682680944, 0.018053968510807
    return np.where(x < b, 4.5 * x, a * np.maximum(x, b) ** 0.45 - (a - 1))


def _romm(x):  # ISO 22028-2 5.3, written out
    return np.where(x < 1 / 512, 16 * x, np.maximum(x, 1 / 512) ** (1 / 1.8))


def _srgb(x):  # IEC 61966-2-1 5.3, written out
    return np.where(
        x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055
    )


@pytest.mark.parametrize(
    "curve, formula", [(SRGB_CURVE, _srgb), (BT2020_CURVE, _bt2020), (ROMM_CURVE, _romm)]
)
def test_toe_curves(curve, formula):
    x = np.concatenate([np.linspace(0, 1, 4097), [0.18, 0.001, 0.01, curve.encode_knee]])
    assert np.allclose(curve.encode(x), formula(x), rtol=0, atol=1e-12)
    assert curve.encode(np.array(1.0)) == pytest.approx(1.0, abs=1e-15)
    k = curve.encode_knee
    # continuous at the knee (sRGB's rounded constants leave a 3e-8 step: far below a code)
    assert abs(curve.encode(np.array(k * (1 + 1e-9))) - curve.encode(np.array(k))) < 1e-7
    wide = np.linspace(-0.5, 2.0, 2001)  # beyond [0, 1]: linear toe below, power law above
    assert np.allclose(curve.decode(curve.encode(wide)), wide, rtol=1e-12, atol=1e-15)
    assert np.array_equal(curve.encode(np.array([-0.25])), [-0.25 * curve.slope])
    # the one formula serves numpy (engine tables) and torch (reference) alike
    t = curve.encode(torch.from_numpy(wide)).numpy()
    assert np.allclose(t, curve.encode(wide), rtol=1e-15, atol=0)


def test_bt2020_constants_are_the_rounded_ones():
    """BT.709's (and 10-bit BT.2020's) 1.099/0.018 are these constants rounded."""
    x = np.linspace(0, 1, 1001)
    rounded = np.where(x < 0.018, 4.5 * x, 1.099 * x**0.45 - 0.099)
    assert np.abs(BT2020_CURVE.encode(x) - rounded).max() < 3e-4  # 0.08 of an 8-bit code


@pytest.mark.parametrize("name", ["srgb", "bt2020", "romm", "gamma:563/256", "linear"])
def test_transfers_gradcheck(name):
    spec = TransferSpec.parse(name)
    if spec.kind == "gamma":  # the odd power law's slope is unbounded at 0: stay off it
        x = torch.linspace(0.05, 1.3, 17, dtype=torch.float64)
    else:  # the toe curves, negative values and knees included
        x = torch.linspace(-0.2, 1.3, 31, dtype=torch.float64)
        if spec.curve is not None:
            knees = torch.tensor([spec.curve.encode_knee, spec.curve.decode_knee])
            x = torch.cat([x, knees.double() * 1.01, knees.double() * 0.99])
    x.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: apply_transfer(t, spec), (x,))
    assert torch.autograd.gradcheck(lambda t: invert_transfer(t, spec), (x,))
    if spec.curve is not None:  # finite at 0: the toe's slope
        zero = torch.zeros(1, dtype=torch.float64, requires_grad=True)
        apply_transfer(zero, spec).backward()
        assert zero.grad.item() == pytest.approx(spec.curve.slope)


def test_transfer_names_and_auto():
    assert str(TransferSpec.parse("gamma:563/256")) == "gamma:2.19921875"
    assert TransferSpec.parse("gamma:2.19921875").gamma == ADOBE_RGB_GAMMA
    assert str(TransferSpec.parse("gamma:2.2")) == "gamma:2.2"
    own = {s: str(space_transfer(s)) for s in OUTPUT_SPACES}
    assert own == {
        "srgb": "srgb",
        "display-p3": "srgb",
        "adobe-rgb": "gamma:2.19921875",
        "rec2020": "bt2020",
        "aces2065-1": "linear",
        "acescg": "linear",
        "prophoto": "romm",
        "xyz": "srgb",
        "camera": "srgb",
    }
    assert TransferStage().function == "auto"
    config = IspConfig.default().override(output_space="prophoto")
    assert TransferStage().spec_for("prophoto").kind == "romm"
    assert "auto" in config.to_toml() and IspConfig.from_toml(config.to_toml()) == config
    with pytest.raises(ParameterError, match="auto"):
        IspConfig.default().override(transfer="pq")
    with pytest.raises(ParameterError, match="display-p3"):
        IspConfig.default().override(output_space="p3")


# ------------------------------------------------------------------ profiles
ENCODINGS = [
    Encoding(s, t) for s in TAGGED for t in (str(space_transfer(s)), "linear", "gamma:2.2")
]


def _tags(profile: bytes) -> dict[bytes, bytes]:
    (count,) = struct.unpack(">I", profile[128:132])
    tags = {}
    for k in range(count):
        sig, at, size = struct.unpack(">4sII", profile[132 + 12 * k : 144 + 12 * k])
        tags[sig] = profile[at : at + size]
    return tags


def _fixed(data: bytes) -> np.ndarray:
    return np.array(struct.unpack(f">{len(data) // 4}i", data)) / 65536


@pytest.mark.parametrize("encoding", ENCODINGS, ids=lambda e: f"{e.space}-{e.transfer}")
def test_profiles_parse_and_are_reproducible(encoding):
    profile = icc_profile(encoding)
    assert icc_profile.__wrapped__(encoding) == profile  # built again, not cached: same bytes
    size, version, cls, space, pcs = struct.unpack(">I4xI4s4s4s", profile[:24])
    assert (size, version, cls, space, pcs) == (len(profile), 0x04300000, b"mntr", b"RGB ", b"XYZ ")
    assert struct.unpack(">6H", profile[24:36]) == PROFILE_DATE and profile[36:40] == b"acsp"
    zeroed = bytearray(profile)
    zeroed[44:48] = zeroed[64:68] = b"\0" * 4
    zeroed[84:100] = b"\0" * 16
    assert hashlib.md5(zeroed).digest() == profile[84:100]  # the profile ID (ICC.1 7.2.18)
    tags = _tags(profile)
    colour_tags = {b"rXYZ", b"gXYZ", b"bXYZ", b"rTRC", b"gTRC", b"bTRC"}
    assert set(tags) == {b"desc", b"cprt", b"wtpt", b"chad", *colour_tags}
    assert np.allclose(_fixed(tags[b"wtpt"][8:]), XYZ_D50, atol=1e-5)
    columns = np.stack([_fixed(tags[c][8:]) for c in (b"rXYZ", b"gXYZ", b"bXYZ")], axis=1)
    if encoding.space == "xyz":  # X, Y, Z themselves: D65's XYZ is white
        assert np.allclose(columns @ XYZ_D65, XYZ_D50, atol=1e-4)
    else:  # RGB (1, 1, 1) is exactly D50 as written
        assert np.array_equal(columns.sum(axis=1), np.round(XYZ_D50 * 65536) / 65536)
    assert np.abs(columns - colorants(encoding)[1]).max() <= 2 / 65536
    trc = tags[b"rTRC"]
    kind, params = struct.unpack(">H", trc[8:10])[0], _fixed(trc[12:])
    curve = encoding.transfer.curve
    if curve is not None:
        assert kind == 3 and np.allclose(params, curve.icc_parameters(), atol=1e-5)
    else:
        assert kind == 0 and params[0] == pytest.approx(encoding.transfer.gamma, abs=1e-5)
    # LittleCMS (through Pillow) reads it and names it
    parsed = ImageCms.ImageCmsProfile(io.BytesIO(profile))
    assert ImageCms.getProfileDescription(parsed).strip() == encoding.describe()
    assert parsed.profile.xcolor_space.strip() == "RGB" and parsed.profile.version == 4.3


def _transicc(profile: bytes, encoded: np.ndarray, target: str, tmp_path) -> np.ndarray:
    """LittleCMS's relative colorimetric conversion (unquantised, -c0) to ``target``."""
    src = tmp_path / "in.icc"
    src.write_bytes(profile)
    lines = "\n".join(" ".join(f"{255 * c:.7f}" for c in row) for row in encoded) + "\n"
    done = subprocess.run(
        [require_tool("transicc"), "-t1", "-c0", "-n", f"-i{src}", f"-o{target}"],
        input=lines,
        capture_output=True,
        text=True,
        check=True,
    )
    return np.array([[float(v) for v in line.split()] for line in done.stdout.splitlines()]) / 255


@pytest.mark.parametrize("encoding", ENCODINGS, ids=lambda e: f"{e.space}-{e.transfer}")
def test_lcms_converts_our_values_back_to_srgb(encoding, tmp_path):
    """Colours rawsim encodes in a space, decoded by LittleCMS through the profile and
    encoded as sRGB, are rawsim's own sRGB: within 1e-4 (the profiles' s15Fixed16 steps)
    with rawsim's sRGB profile, and within 5e-4 with LittleCMS's built-in sRGB (built
    from xy (0.3127, 0.3290); rawsim's D65 is ASTM E308's)."""
    rng = np.random.default_rng(7)
    linear_srgb = rng.uniform(0.02, 0.95, (64, 3))
    linear = linear_srgb @ space_from_srgb(encoding.space).T
    encoded = apply_transfer(torch.from_numpy(linear), encoding.transfer).numpy()
    inside = ((encoded >= 0) & (encoded <= 1)).all(axis=1)
    assert inside.sum() > 50
    want = SRGB_CURVE.encode(linear_srgb[inside])
    ours = tmp_path / "srgb.icc"
    ours.write_bytes(icc_profile(Encoding("srgb", "srgb")))
    got = _transicc(icc_profile(encoding), encoded[inside], str(ours), tmp_path)
    assert np.abs(got - want).max() < 1e-4
    got = _transicc(icc_profile(encoding), encoded[inside], "*sRGB", tmp_path)
    assert np.abs(got - want).max() < 5e-4


def test_grey_profile(tmp_path):
    encoding = Encoding("prophoto", "romm")
    profile = icc_profile(encoding, grey=True)
    assert profile[16:20] == b"GRAY" and set(_tags(profile)) == {
        b"desc",
        b"cprt",
        b"wtpt",
        b"chad",
        b"kTRC",
    }
    assert ImageCms.ImageCmsProfile(io.BytesIO(profile)).profile.xcolor_space.strip() == "GRAY"
    grey = np.arange(64 * 48, dtype=np.uint16).reshape(48, 64, 1) * 20
    write_image(tmp_path / "g.tif", grey, "tiff", encoding)
    with tifffile.TiffFile(tmp_path / "g.tif") as tif:
        assert tif.pages[0].tags[34675].value == profile
        assert np.array_equal(tif.pages[0].asarray(), grey[..., 0])


# ------------------------------------------------------------------ files
def _process(out, *args) -> None:
    r = CliRunner().invoke(
        cli, ["process", str(RAW), "-o", str(out), "--overwrite", *map(str, args)]
    )
    assert r.exit_code == 0, r.output


def _png_chunks(path) -> dict[bytes, list[bytes]]:
    data = path.read_bytes()
    at, chunks = 8, {}
    while at < len(data):
        (size,) = struct.unpack(">I", data[at : at + 4])
        chunks.setdefault(data[at + 4 : at + 8], []).append(data[at + 8 : at + 8 + size])
        at += 12 + size
    return chunks


#: H.273 code points the PNGs must carry: (primaries, transfer, matrix, full range).
CICP = {"srgb": (1, 13, 0, 1), "display-p3": (12, 13, 0, 1), "rec2020": (9, 1, 0, 1)}


@pytest.mark.parametrize("space", OUTPUT_SPACES)
def test_png_tags(space, tmp_path):
    _process(tmp_path, "--output-space", space, "--format", "png")  # ACES's default: EXR
    chunks = _png_chunks(tmp_path / "canon_eos60d_mlv.png")
    cicp = chunks.get(b"cICP")
    assert (cicp and tuple(cicp[0])) == CICP.get(space)
    if space == "camera":
        assert not {b"iCCP", b"sRGB", b"gAMA", b"cHRM"} & set(chunks)
    elif space == "srgb":  # PNG's own sRGB chunk is its profile
        assert b"sRGB" in chunks and b"iCCP" not in chunks
    else:
        assert not {b"sRGB", b"gAMA", b"cHRM"} & set(chunks)  # they would contradict iCCP
        name, rest = chunks[b"iCCP"][0].split(b"\0", 1)
        encoding = Encoding(space, space_transfer(space))
        assert name.decode() == encoding.describe() and rest[0] == 0
        assert zlib.decompress(rest[1:]) == icc_profile(encoding)
    (tmp_path / "canon_eos60d_mlv.png").unlink()
    _process(
        tmp_path, "--output-space", space, "--transfer", "linear", "--bits", "16",
        "--format", "png",
    )  # fmt: skip
    chunks = _png_chunks(tmp_path / "canon_eos60d_mlv.png")
    if space != "camera":  # linear light gets a linear profile, sRGB included
        profile = zlib.decompress(chunks[b"iCCP"][0].split(b"\0", 1)[1][1:])
        assert profile == icc_profile(Encoding(space, "linear"))
    if space in CICP:
        assert tuple(chunks[b"cICP"][0]) == CICP[space][:1] + (8, 0, 1)


@pytest.mark.parametrize("strip", [False, True], ids=["metadata", "stripped"])
@pytest.mark.parametrize("space", ["srgb", "adobe-rgb", "prophoto", "xyz", "camera"])
def test_tiff_and_jpeg_embed_the_profile(space, strip, tmp_path):
    """TIFF tag 34675 and JPEG APP2, with the photo's metadata (rawsim's TIFF writer,
    exiv2) and without (OpenImageIO); read back by tifffile, exiftool, OpenImageIO."""
    extra = ["--strip-metadata"] if strip else []
    want = None if space == "camera" else icc_profile(Encoding(space, space_transfer(space)))
    _process(tmp_path, "--output-space", space, "--format", "tiff", "--bits", "16", *extra)
    _process(tmp_path, "--output-space", space, "--format", "jpg", *extra)
    tif, jpg = tmp_path / "canon_eos60d_mlv.tif", tmp_path / "canon_eos60d_mlv.jpg"
    with tifffile.TiffFile(tif) as f:
        tag = f.pages[0].tags.get(34675)
        assert (tag and tag.value) == want
    exiftool = require_tool("exiftool")
    for path in (tif, jpg):
        got = subprocess.run([exiftool, "-b", "-ICC_Profile", str(path)], capture_output=True)
        assert got.stdout == (want or b"")
        spec = oiio.ImageInput.open(str(path)).spec()
        icc = spec.getattribute("ICCProfile")
        assert (None if icc is None else bytes(np.asarray(icc, np.uint8))) == want


@pytest.mark.parametrize("space", TAGGED)
def test_exr_chromaticities(space, tmp_path):
    _process(tmp_path, "--output-space", space, "--format", "exr")
    spec = oiio.ImageInput.open(str(tmp_path / "canon_eos60d_mlv.exr")).spec()
    want = Encoding(space, "linear").chromaticities
    assert np.allclose(spec.getattribute("chromaticities"), want, atol=1e-7)
    if space != "xyz":
        rgb = RGB_SPACES[space]
        assert want == (*(c for xy in rgb.primaries for c in xy), *rgb.white_xy)
    else:  # OpenEXR's XYZ, and D65 as the neutral
        assert want == (1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1 / 3, 1 / 3)
        assert np.allclose(spec.getattribute("adoptedNeutral"), (0.3127, 0.3290), atol=1e-7)


# ------------------------------------------------------------------ renders
@pytest.fixture(scope="module")
def srgb_render(tmp_path_factory):
    out = tmp_path_factory.mktemp("srgb")
    _process(out, "--format", "tiff", "--bits", "16")
    return tifffile.imread(out / "canon_eos60d_mlv.tif").astype(np.float64) / 65535


#: PSNR (dB) each space's render must reach against the sRGB render once a colour-managed
#: reader converts it back, on the pixels both render unclipped.
ROUND_TRIP_DB = 40.0


@pytest.mark.parametrize("space", TAGGED)
def test_render_converts_back_to_srgb_with_tificc(space, srgb_render, tmp_path):
    _process(tmp_path, "--output-space", space, "--format", "tiff", "--bits", "16")
    ours = tifffile.imread(tmp_path / "canon_eos60d_mlv.tif")
    back = tmp_path / "back.tif"
    # -c0: LittleCMS's exact transform; its default 16-bit tables cost it 53–82 dB here
    tificc = [require_tool("tificc"), "-t1", "-w16", "-c0"]
    subprocess.run([*tificc, str(tmp_path / "canon_eos60d_mlv.tif"), str(back)], check=True)
    converted = tifffile.imread(back).astype(np.float64) / 65535
    inside = ((srgb_render > 0) & (srgb_render < 1)).all(-1) & ((ours > 0) & (ours < 65535)).all(-1)
    assert inside.mean() > 0.9
    db = psnr(converted[inside], srgb_render[inside])
    print(f"{space}: {db:.1f} dB through tificc")
    assert db >= ROUND_TRIP_DB
    codes = 8  # every pixel; linear spaces (ACES) are coarser near black, where the sRGB
    if str(space_transfer(space)) == "linear":  # curve's slope is 12.92: half a code
        back_to_srgb = np.linalg.inv(space_from_srgb(space))  # there, through the matrix
        codes = math.ceil(0.5 * 12.92 * np.abs(back_to_srgb).sum(1).max()) + 2
    assert np.abs(converted - srgb_render)[inside].max() <= codes / 65535


@pytest.mark.parametrize("space", SPACES)
def test_png_converts_back_to_srgb_with_pillow(space, tmp_path):
    """8-bit PNGs through Pillow's ImageCms (LittleCMS) with the embedded iCCP."""
    _process(tmp_path / "srgb")
    _process(tmp_path / space, "--output-space", space, "--format", "png")
    ref = np.asarray(Image.open(tmp_path / "srgb" / "canon_eos60d_mlv.png"), np.float64)
    image = Image.open(tmp_path / space / "canon_eos60d_mlv.png")
    if space == "srgb":
        assert "icc_profile" not in image.info and image.info.get("srgb") == 0
        return
    embedded = ImageCms.ImageCmsProfile(io.BytesIO(image.info["icc_profile"]))
    srgb = ImageCms.createProfile("sRGB")
    back = ImageCms.profileToProfile(image, embedded, srgb, renderingIntent=1, outputMode="RGB")
    back = np.asarray(back, np.float64)
    inside = ((ref > 0) & (ref < 255)).all(-1)
    db = psnr(back[inside], ref[inside], 255)
    print(f"{space}: {db:.1f} dB through Pillow (8 bits)")
    assert db >= ROUND_TRIP_DB


def test_sidecar_records_the_transfer(tmp_path):
    import json

    _process(tmp_path, "--output-space", "adobe-rgb")
    side = json.loads((tmp_path / "canon_eos60d_mlv.process.json").read_text())
    assert side["transfer"] == "gamma:2.19921875"
    transfer = next(s for s in side["config"] if s["name"] == "transfer")
    assert transfer["function"] == "auto"


def test_aces_matrices_equal_colour_sciences():
    """sRGB → ACES2065-1 and ACEScg, Bradford-adapted from D65 to the ACES white, as
    colour-science forms them (rawsim's sRGB matrix is IEC's, rounded: 5e-4)."""
    import colour

    for space, name in (("aces2065-1", "ACES2065-1"), ("acescg", "ACEScg")):
        want = colour.matrix_RGB_to_RGB(
            colour.RGB_COLOURSPACES["sRGB"], colour.RGB_COLOURSPACES[name], "Bradford"
        )
        assert np.abs(space_from_srgb(space) - want).max() < 5e-4, space


@pytest.mark.parametrize("space", ["aces2065-1", "acescg"])
def test_aces_output_is_openexr_and_the_container(space, tmp_path):
    """Without --format, an ACES space writes OpenEXR; ACES2065-1 in half floats is the
    ACES container of SMPTE ST 2065-4 (uncompressed, acesImageContainerFlag 1, AP0
    chromaticities, the ACES white as the adopted neutral), read back by OpenEXR."""
    import json

    import OpenEXR

    _process(tmp_path, "--output-space", space)
    path = tmp_path / "canon_eos60d_mlv.exr"
    header = OpenEXR.File(str(path)).header()
    want = Encoding(space, "linear").chromaticities
    assert np.allclose(header["chromaticities"], want, atol=1e-7)
    assert np.allclose(header["adoptedNeutral"], (0.32168, 0.33767), atol=1e-7)
    side = json.loads((tmp_path / "canon_eos60d_mlv.process.json").read_text())
    assert side["format"] == "exr" and side["bits"] == 16
    assert side["aces"]["idt"]["kind"] == "matrix"  # no measured curves for the 60D
    assert side["aces"]["idt"]["how"].startswith("from the colour matrix")
    if space == "aces2065-1":
        assert header["acesImageContainerFlag"] == 1
        assert header["compression"] == OpenEXR.NO_COMPRESSION
        assert side["aces"]["container"] == "SMPTE ST 2065-4"
    else:
        assert "acesImageContainerFlag" not in header
        assert side["aces"]["container"] is None
