"""``quickhealth examples``: the README tutorial's example data in a folder.

quickhealth examples [--out DIR] [--sim-image-scale S]
    DIR/l/*.png, DIR/r/*.png: a ChArUco board (charuco:10x7:60:45:DICT_4X4_50) seen by the
    simulated cell's stereo camera from 8 places (``vision calibrate`` reads them);
    DIR/export.csv: a laser tracker export of a simulated UR10 in the ipa-ur10 layout
    (``import tracker``).  The images have the simulated camera's size (``run --sim``'s
    --sim-image-scale or $QUICKHEALTH_SIM_IMAGE_SCALE, default 0.5), so a calibration made
    from them measures a ``run --sim`` folder (``vision measure RUN --calibration cal.json``).
    Refused (one line, exit 2, nothing written) when one of these is there already.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ...identify.errors import InputError


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``examples``."""
    e = subparsers.add_parser(
        "examples",
        help="write the tutorial's example data: calibration images and a tracker export",
        description="Calibration images of a ChArUco board seen by the simulated cell's "
        "stereo camera (l/, r/) and a laser tracker export of a simulated UR10 (export.csv).",
    )
    e.add_argument("--out", type=Path, default=Path("."), help="folder (default: here)")
    e.add_argument(
        "--sim-image-scale",
        type=float,
        default=None,
        help="image size relative to the reference camera, as run --sim's (default: "
        "$QUICKHEALTH_SIM_IMAGE_SCALE, else 0.5)",
    )
    e.set_defaults(func=_examples)


def _examples(args: argparse.Namespace) -> int:
    import cv2  # the images' PNG writer

    from ...vision.reference import reference_rig
    from ..formats import write_text_atomic
    from ..fsio import make_dirs, write_atomic
    from ..services.examples import BOARD, calibration_views, tracker_export
    from ..sim.cameras import scaled_rig
    from .run import SIM_IMAGE_SCALE_ENV, _sim_setting

    out: Path = args.out
    names = [out / "l", out / "r", out / "export.csv"]
    there = [str(p) for p in names if p.exists()]
    if there:
        raise InputError(f"{there[0]}: exists already: give another --out (nothing written)")
    scale = _sim_setting(
        args.sim_image_scale, "--sim-image-scale", SIM_IMAGE_SCALE_ENV, 0.5, (0.05, 1.0)
    )
    rig = scaled_rig(reference_rig(), scale)
    print(f"rendering {BOARD} in the simulated stereo camera ({rig.left.image_size[0]} px wide)…")
    views = calibration_views(rig)
    for side, images in (("l", views.left), ("r", views.right)):
        make_dirs(out / side)
        for i, img in enumerate(images):
            ok, png = cv2.imencode(".png", img)
            if not ok:
                raise InputError(f"{out / side}: could not encode image {i}")
            write_atomic(out / side / f"view{i + 1:02d}.png", png.tobytes())
    write_text_atomic(out / "export.csv", tracker_export())
    cl, cr = views.coverage
    print(
        f"wrote {len(views.left)} stereo pairs in {out / 'l'}, {out / 'r'} (the board's corners "
        f"reach {cl:.0%} and {cr:.0%} of the two images) and {out / 'export.csv'} (a simulated "
        "UR10 measured by a laser tracker, ipa-ur10 layout)"
    )
    return 0
