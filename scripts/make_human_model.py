"""Write a calibrate human model URDF for a given height and mass.

    python scripts/make_human_model.py --height 1.75 --mass 75 --out models/human.urdf
    python scripts/make_human_model.py --girdle --out models/human_girdle.urdf

models/human.urdf in the repository is this script's output with its defaults, models/human_girdle.urdf with
--girdle (a clavicle segment on each side carrying the shoulder and the acromion marker).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from calibrate.model.human import build_human_urdf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--height", type=float, default=1.75, help="standing height (m), default 1.75")
    ap.add_argument("--mass", type=float, default=75.0, help="body mass (kg), default 75")
    ap.add_argument("--name", default="human", help="robot name in the URDF")
    ap.add_argument("--girdle", action="store_true",
                    help="a shoulder girdle: a clavicle segment per side between the torso and the shoulder")
    ap.add_argument("--out", type=Path, default=Path("models/human.urdf"), help="output URDF path")
    a = ap.parse_args()
    a.out.write_text(build_human_urdf(a.height, a.mass, a.name, girdle=a.girdle))
    print(f"wrote {a.out} (height {a.height} m, mass {a.mass} kg)")


if __name__ == "__main__":
    main()
