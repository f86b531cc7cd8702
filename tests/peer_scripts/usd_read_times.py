"""Run by tests in a peer venv with another usd-core (no numpy needed): read a stage's
attributes at given times and flatten it, so the test can compare with what usd-core 26 reads.

usage: python usd_read_times.py STAGE REQUEST.json OUT.json FLAT.usda
REQUEST: {"attributes": {"/prim/path": ["attr", ...]}, "times": [0, 0.5, ...]}
OUT: {"version": [...], "has_splat_schema": bool, "types": {prim: type name},
      "listed": {prim: [attribute names GetAttributes() gives]},
      "values": {prim: {attr: {time: flat list of floats | null}}}, "errors": [...]}
"""
import json
import sys

from pxr import Usd, UsdVol


def flat(value):
    out = []
    for item in value:
        if hasattr(item, "GetReal"):  # quaternions: w, x, y, z
            out += [item.GetReal(), *item.GetImaginary()]
        elif hasattr(item, "__len__"):
            out += list(item)
        else:
            out.append(item)
    return [float(x) for x in out]


def main(stage_path, request_path, out_path, flat_path):
    request = json.load(open(request_path))
    stage = Usd.Stage.Open(stage_path)
    report = {"version": list(Usd.GetVersion()),
              "has_splat_schema": hasattr(UsdVol, "ParticleField3DGaussianSplat"),
              "types": {}, "listed": {}, "values": {}, "errors": []}
    for prim_path, names in request["attributes"].items():
        prim = stage.GetPrimAtPath(prim_path)
        report["types"][prim_path] = str(prim.GetTypeName())
        report["listed"][prim_path] = sorted(a.GetName() for a in prim.GetAttributes())
        values = report["values"][prim_path] = {}
        for name in names:
            attr = prim.GetAttribute(name)
            values[name] = {}
            for t in request["times"]:
                try:
                    v = attr.Get(t)
                except Exception as e:  # a Tf error: what an older USD says
                    report["errors"].append(f"{prim_path}.{name} at {t}: {str(e).strip().splitlines()[-1]}")
                    v = None
                values[name][repr(float(t))] = None if v is None else flat(v)
    stage.Flatten().Export(flat_path)
    json.dump(report, open(out_path, "w"))


if __name__ == "__main__":
    main(*sys.argv[1:5])
