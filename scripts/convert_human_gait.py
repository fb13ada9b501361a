"""Convert GaitAnalysisToolKit's sagittal marker recording into bemlearn's human gait CSV.

    python scripts/convert_human_gait.py --source SRC [--out data/human_gait/human_gait_right.csv]

SRC is either the raw file ``gaitanalysis/octave/2d_inverse_dynamics/test/rawdata.txt`` or
the PyPI source distribution ``GaitAnalysisToolKit-0.2.0.tar.gz`` that contains it
(``pip download --no-deps gaitanalysistoolkit==0.2.0``).  The conversion itself is
:func:`bemlearn.apps.biped.human_gait.convert_raw` (angle definitions in its module docstring);
the output is deterministic, so re-running reproduces the shipped file byte for byte.
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import sys
import tarfile
from pathlib import Path

from bemlearn.apps.biped.human_gait import HUMAN_GAIT_CSV, convert_raw, format_csv

#: Path of the raw file inside the package source tree.
MEMBER = "gaitanalysis/octave/2d_inverse_dynamics/test/rawdata.txt"
#: SHA-256 of the raw file in GaitAnalysisToolKit 0.2.0.
RAW_SHA256 = "07a3294ff4e15d5f2a57680857ac6ec39300b58fbbb99aba1eec8d2af08c0f58"

log = logging.getLogger("convert_human_gait")


def read_source(path: Path) -> bytes:
    """The raw file's bytes, from the file itself or from the sdist tarball."""
    if not path.exists():
        raise FileNotFoundError(f"{path}: source not found (rawdata.txt or GaitAnalysisToolKit-0.2.0.tar.gz)")
    if path.name.endswith((".tar.gz", ".tgz")):
        with tarfile.open(path, "r:gz") as tar:
            names = [n for n in tar.getnames() if n.endswith(MEMBER)]
            if not names:
                raise ValueError(f"{path}: archive has no member ending in {MEMBER}")
            fh = tar.extractfile(names[0])
            if fh is None:
                raise ValueError(f"{path}: {names[0]} is not a regular file")
            return fh.read()
    return path.read_bytes()


def convert(source: Path, *, max_gap: int = 5) -> str:
    """The CSV text for ``source`` (see module docstring)."""
    raw = read_source(source)
    digest = hashlib.sha256(raw).hexdigest()
    if digest != RAW_SHA256:
        log.warning("%s: SHA-256 %s differs from GaitAnalysisToolKit 0.2.0's %s", source, digest, RAW_SHA256)
    table = convert_raw(raw.decode("utf-8"), source=str(source), max_gap=max_gap)
    provenance = (
        f"source: GaitAnalysisToolKit 0.2.0 (Apache-2.0), {MEMBER}, sha256 {digest}; "
        "right side, 100 Hz; angles in the robot convention (bemlearn.apps.biped.human_gait); "
        "made by scripts/convert_human_gait.py"
    )
    return format_csv(table, provenance=provenance)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", type=Path, required=True, help="rawdata.txt or the 0.2.0 sdist (.tar.gz)")
    parser.add_argument("--out", type=Path, default=HUMAN_GAIT_CSV, help=f"output CSV (default {HUMAN_GAIT_CSV})")
    parser.add_argument("--max-gap", type=int, default=5, help="longest marker gap (samples) to interpolate")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        text = convert(args.source, max_gap=args.max_gap)
    except (ValueError, FileNotFoundError) as exc:
        print(f"convert_human_gait: error: {exc}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text, encoding="utf-8", newline="\n")
    log.info("wrote %s (%d rows)", args.out, text.count("\n") - 3)
    return 0


if __name__ == "__main__":
    sys.exit(main())
