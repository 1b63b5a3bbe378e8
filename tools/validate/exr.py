"""Reads OpenEXR distance slices written by stablesurf with the OpenEXR Python bindings.

Usage: python tools/validate/exr.py FILE.exr [FILE.exr ...]

For every file: it must open, hold exactly one channel `Y` of 32-bit float samples, use a lossless
compression, hold no NaN, and carry stablesurf's header attributes (gridToWorld, voxelSize,
sliceAxis, sliceIndex, sliceCount, signConvention, distanceMethod, distanceUnits).

Prints one JSON line per file: {"file", "width", "height", "channels", "compression", "min",
"max", "attributes", "problems"}, and exits 0 when every file passed, 1 otherwise, 2 when the
bindings are not installed.
"""

import json
import sys

REQUIRED = [
    "gridToWorld",
    "voxelSize",
    "sliceAxis",
    "sliceIndex",
    "sliceCount",
    "signConvention",
    "distanceMethod",
    "distanceUnits",
]
LOSSLESS = {"NO_COMPRESSION", "RLE_COMPRESSION", "ZIPS_COMPRESSION", "ZIP_COMPRESSION", "PIZ_COMPRESSION"}


def plain(value):
    """Turns an attribute value into something JSON can hold."""
    import numpy as np

    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return str(value)


def check(path):
    import numpy as np
    import OpenEXR

    problems = []
    with OpenEXR.File(path) as f:
        header = f.header()
        channels = f.channels()
        names = sorted(channels.keys())
        report = {"file": path, "channels": names}
        if names != ["Y"]:
            problems.append(f"channels are {names}, expected ['Y']")
        compression = str(header.get("compression"))
        report["compression"] = compression.split(".")[-1]
        if report["compression"] not in LOSSLESS:
            problems.append(f"compression {compression} is lossy or unknown")
        for name in REQUIRED:
            if name not in header:
                problems.append(f"attribute {name} missing")
        report["attributes"] = {k: plain(header[k]) for k in REQUIRED if k in header}
        if "Y" in channels:
            pixels = channels["Y"].pixels
            report["height"], report["width"] = (int(s) for s in pixels.shape)
            report["dtype"] = str(pixels.dtype)
            if pixels.dtype != np.float32:
                problems.append(f"channel Y holds {pixels.dtype}, expected float32")
            if np.isnan(pixels).any():
                problems.append(f"{int(np.isnan(pixels).sum())} NaN samples")
            report["min"] = float(np.nanmin(pixels))
            report["max"] = float(np.nanmax(pixels))
            report["negative"] = int((pixels < 0).sum())
            report["positive"] = int((pixels > 0).sum())
    report["problems"] = problems
    return report


def main():
    files = sys.argv[1:]
    if not files:
        print(__doc__, file=sys.stderr)
        return 2
    try:
        import OpenEXR  # noqa: F401
    except ImportError as err:
        print(f"validator not installed: {err}", file=sys.stderr)
        return 2
    failed = False
    for path in files:
        try:
            report = check(path)
        except Exception as err:  # an unreadable file is a validation failure
            report = {"file": path, "problems": [f"{type(err).__name__}: {err}"]}
        failed |= bool(report["problems"])
        print(json.dumps(report))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
