#!/usr/bin/env python
"""Write the target lighting of a relight (lightcrafter.lighting/1) from config relight.

  relight_lighting.py --settings-json '{"hdri": "sky.exr", "rotation_deg": 90, "strength": 1,
                                        "point_lights": [...], "area_lights": [...]}' --out lighting.json

The HDRI is read and checked first (a lat-long EXR of finite, non-negative linear radiance): a
missing file, a file that is not an EXR, or NaN/Inf/negative texels are one line naming the file.
Point and area lights have edits.light's fields (world frame, metres; W/sr and W/(m^2 sr)).
"""

import argparse
import math
from pathlib import Path

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter import io


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--settings-json", required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    from lightcrafter import envmap
    from lightcrafter.proxy.lighting import write_lighting_file

    s = _cli.json_arg(a.settings_json)
    hdri = s.get("hdri")
    if hdri:
        from lightcrafter.lights import BUILTIN_PREFIX, resolve_hdri

        p = Path(resolve_hdri(hdri)) if hdri.startswith(BUILTIN_PREFIX) else Path(hdri)
        if not p.is_file():
            raise io.DataError(f"{p}: HDRI not found; set relight.hdri to a lat-long .exr")
        try:
            env = envmap.load(p)  # validates: finite, non-negative radiance
        except io.DataError:
            raise
        except Exception as exc:  # noqa: BLE001 (not an EXR at all)
            raise io.DataError(f"{p}: not a readable OpenEXR environment map ({type(exc).__name__}); give a "
                               "lat-long .exr (convert .hdr/.jpg with an HDR tool first)") from None
        hdri = str(p.resolve())
    elif not (s.get("point_lights") or s.get("area_lights")):
        raise io.DataError("relight: no target lighting; set relight.hdri and/or relight.point_lights / area_lights")
    if hdri is None:
        env = None
    write_lighting_file(a.out, env=hdri, strength=float(s.get("strength", 1.0)),
                        rotation_z_rad=math.radians(float(s.get("rotation_deg", 0.0))),
                        point_lights=s.get("point_lights"), area_lights=s.get("area_lights"))
    print(f"relight_lighting: {'HDRI ' + hdri + f' {env.shape[1]}x{env.shape[0]}' if hdri else 'local lights'}, "
          f"{len(s.get('point_lights') or [])} point and {len(s.get('area_lights') or [])} area lights -> {a.out}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "relight_lighting", (io.DataError,))
