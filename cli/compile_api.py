"""``rawsim compile``'s runs of the Python API: ``python -m rawsim_cli.compile_api TASK IN``.

numba compiles a kernel once per signature: the types and memory layouts of its
arrays. The Python API hands the kernels arrays the command line's files never
do: views of tensors (a Dataset's crops: any strides), int32 codes of 16-bit
images, float32 outputs written into tensors, X-Trans renders to floats. Each task
here calls the API as a user's code does, on the tiny images of ``IN`` (made by
:func:`rawsim_cli.compile._inputs`), so that those signatures are compiled too:

* ``dataset``: :class:`rawsim.UnprocessDataset` items (8-bit, 16-bit and EXR
  crops) for a Bayer, an X-Trans and a mono sensor, as DataLoader workers make them;
* ``unprocess``: :func:`rawsim.unprocess` of whole images of each kind (uint8,
  uint16, int32, display-referred and scene-linear floats), and through a lens;
* ``process``: :func:`rawsim.process` of Bayer, X-Trans and mono mosaics, and at
  half size.

Compiles are logged as by the command line (``rawsim: compiled … in … s``), which
is how ``rawsim compile`` counts them.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

LENS = ("Canon EF-S 18-55mm f/3.5-5.6 IS STM", 18.0, 3.5)


def _sensors():
    import rawsim

    bayer = rawsim.RGBSensor.from_profile("canon_eos_700d")
    return bayer, rawsim.RGBSensor(bayer.profile, cfa="XTRANS"), rawsim.MonoSensor(bayer.profile)


def dataset(folder: Path) -> None:
    """Every item of a Dataset over ``folder``'s photos, for each kind of sensor."""
    import rawsim

    for sensor in _sensors():
        data = rawsim.UnprocessDataset(folder, sensor, crop=48, iso=800, noise="gaussian")
        for i in range(len(data)):
            data[i]


def _images(folder: Path) -> list[tuple[object, dict]]:
    """(1, 3, H, W) tensors of each kind the API takes, with their keyword arguments."""
    import torch

    from rawsim.io.images import read_image
    from rawsim.pipelines.unprocess import image_tensor

    photo, photo16 = read_image(folder / "photo.png"), read_image(folder / "photo16.png")
    linear = read_image(folder / "linear.exr")
    codes8 = image_tensor(photo.pixels)
    return [
        (codes8, {"code_max": 255}),
        (image_tensor(photo16.pixels), {"code_max": 65535}),  # int32
        (torch.from_numpy(photo16.pixels).permute(2, 0, 1)[None], {"code_max": 65535}),
        (codes8.float() / 255, {}),  # display-referred floats
        (image_tensor(linear.pixels), {"display_referred": False}),
    ]


def unprocess(folder: Path) -> None:
    """Each kind of image, with and without a lens, Bayer."""
    import rawsim
    from rawsim.io.lensfun import lens_params

    bayer = _sensors()[0]
    p = bayer.profile
    lens, _ = lens_params(*LENS, None, p.make, p.model, adding=True)
    for image, kw in _images(folder):
        rawsim.unprocess(image, bayer, [1], iso=800, **kw)
        rawsim.unprocess(image, bayer, [1], iso=800, lens=lens, **kw)


def process(folder: Path) -> None:
    """Mosaics of each kind of sensor rendered back, as by default and at half size."""
    import rawsim

    image, kw = _images(folder)[0]
    for sensor in _sensors():
        noisy, _, meta = rawsim.unprocess(image, sensor, [1], iso=800, **kw)
        rawsim.process(noisy, sensor, meta)
        if not isinstance(sensor, rawsim.MonoSensor):  # a mono mosaic has no half size
            rawsim.process(noisy, sensor, meta, demosaic="half")


TASKS = {"dataset": dataset, "unprocess": unprocess, "process": process}


def main(argv: list[str] | None = None) -> None:
    task, folder = argv or sys.argv[1:]
    logging.basicConfig(level=logging.WARNING, format="rawsim: %(message)s", stream=sys.stderr)
    TASKS[task](Path(folder))


if __name__ == "__main__":
    main()
