"""``srvol import PHOTOS --out SCENE``: the command line of :mod:`srvol.capture.importer`."""
from __future__ import annotations

from pathlib import Path

from srvol.cli_parser import image_size


def add_parser(sub) -> None:
    p = sub.add_parser(
        "import", help="turn a folder of flash photos into a scene (poses, normalisation, masks)",
        description="Read the photos (JPEG/PNG/TIFF, 8/16 bit, EXIF orientation, EXIF focal as prior), "
                    "find their poses with pycolmap (SIFT, exhaustive matching, incremental mapping, the "
                    "largest model) or take them from --colmap / --transforms, normalise the object's "
                    "bounding sphere (from the sparse points most views see) into the unit sphere with +z up, "
                    "make masks (flash-lit object vs dimmer background, kept consistent by a visual hull) or "
                    "take --masks, blur and decimate to the working resolution (the Gaussian's sigma becomes "
                    "the scene's PSF), decode sRGB to linear, and write the scene (DESIGN.md section 4).")
    p.add_argument("photos", type=Path, help="folder of photos")
    p.add_argument("--out", type=Path, required=True, help="scene folder to write")
    p.add_argument("--lr", type=image_size,
                   help="working resolution WxH: the photo size divided by a whole factor (default: the "
                        "smallest factor that brings the longest side to 400 or less; printed)")
    p.add_argument("--colmap", type=Path, help="take the poses from this COLMAP sparse model (text or binary)")
    p.add_argument("--transforms", type=Path,
                   help="take the poses from this nerfstudio / instant-ngp transforms.json")
    p.add_argument("--masks", type=Path, help="folder of masks (same stems as the photos, photo size)")
    p.add_argument("--force", action="store_true", help="replace an existing --out folder")
    p.set_defaults(func=run_import)


def run_import(args) -> int:
    from srvol.capture.importer import ImportOptions, import_capture

    report = import_capture(args.photos, args.out, ImportOptions(
        lr=args.lr, colmap=args.colmap, transforms=args.transforms, masks=args.masks, force=args.force))
    print(f"photos         {report.photos} ({report.photo_size[0]}x{report.photo_size[1]}; EXIF focal: "
          f"{', '.join(f'{k} {v}' for k, v in report.focal_sources.items())})")
    print(f"registered     {len(report.registered)} of {report.photos} (poses: {report.pose_source})")
    print(f"working size   {report.working_size[0]}x{report.working_size[1]} (photos / {report.factor}; "
          f"--lr to change); PSF sigma {report.psf_sigma_lr_px:.3f} LR px")
    n = report.normalization
    print(f"normalisation  scale {n['scale']:.4g} (object sphere from {report.object_points} sparse points)")
    print(f"masks          {report.masks}")
    print(f"seconds        {report.seconds['total']:.1f}")
    print(f"wrote {args.out}")
    return 0
