"""Check an impm output folder the way ParaView sees it (run with ParaView's pvpython).

Usage:
    xvfb-run -a pvpython scripts/check_output.py OUT_DIR [FIELD[:N] ...] [--png FILE]
        [--nodes FIELD[:N] ...] [--tractions FIELD[:N] ...] [--pressure FIELD[:N] ...]
        [--times T0,T1,...]

Opens OUT_DIR/particles.pvd (and OUT_DIR/grid.pvd, nodes.pvd, tractions.pvd and pressure.pvd
when present)
with ParaView's readers and checks that:
  * the collection is valid XML whose DataSet entries point at existing files, in time order,
    and ParaView reports the same number of time steps (> 0);
  * every named FIELD exists as a point array of particles in every time step, with the right
    number of components: N if given as FIELD:N, else 9 for cauchy_stress and
    deformation_gradient (3x3 row-major), 3 for position/displacement/velocity-like vectors,
    otherwise whatever is found is reported;
  * all point coordinates and every point and cell array of every time step are finite;
  * --nodes / --tractions / --pressure FIELD[:N]: the same for point arrays of nodes.pvd /
    tractions.pvd / pressure.pvd (which must then exist);
  * --times: the particle series' time values (the load factors) are these, to 1e-12.
It prints a short report (time steps, points, cells, arrays with component count and range)
and exits with status 1 and a message on the first failure (2 for a usage error).

--png FILE renders the last time step with scripts/show_stress.py: material points coloured
by the vertical stress, over the background grid's edges, with tractions and point loads.
"""

import argparse
import math
import os
import sys
import xml.etree.ElementTree as ET

# Expected component counts of well-known fields.
KNOWN_COMPONENTS = {
    "cauchy_stress": 9,
    "kirchhoff_stress": 9,
    "deformation_gradient": 9,
    "stress": 9,
    "position": 3,
    "positions": 3,
    "displacement": 3,
    "displacements": 3,
    "velocity": 3,
    "body_force": 3,
    "traction": 3,
    "force": 3,
}

YY = 4  # index of sigma_yy in a row-major 3x3 tensor


class CheckError(Exception):
    """A failed check: reported and turned into exit status 1."""


def read_collection(pvd_path):
    """Parses a .pvd file: [(time, absolute file path)], checking files exist and time order."""
    try:
        root = ET.parse(pvd_path).getroot()
    except (ET.ParseError, OSError) as e:
        raise CheckError(f"{pvd_path}: not a readable XML file: {e}")
    if root.tag != "VTKFile" or root.get("type") != "Collection":
        raise CheckError(f"{pvd_path}: root is not <VTKFile type=\"Collection\">")
    folder = os.path.dirname(os.path.abspath(pvd_path))
    entries = []
    for ds in root.iter("DataSet"):
        name, ts = ds.get("file"), ds.get("timestep")
        if name is None or ts is None:
            raise CheckError(f"{pvd_path}: DataSet without file or timestep: {ds.attrib}")
        try:
            t = float(ts)
        except ValueError:
            raise CheckError(f"{pvd_path}: timestep {ts!r} is not a number")
        if not math.isfinite(t):
            raise CheckError(f"{pvd_path}: timestep {ts!r} is not finite")
        path = os.path.join(folder, name)
        if not os.path.isfile(path):
            raise CheckError(f"{pvd_path}: lists {name}, which does not exist")
        if entries and t < entries[-1][0]:
            raise CheckError(f"{pvd_path}: timestep {t} of {name} is before {entries[-1][0]}")
        entries.append((t, path))
    if not entries:
        raise CheckError(f"{pvd_path}: no time steps")
    return entries


def first_leaf(data):
    """The first non-composite dataset of a reader's output (PVD readers may give a multiblock)."""
    if data is None:
        return None
    if data.IsA("vtkCompositeDataSet"):
        it = data.NewIterator()
        it.InitTraversal()
        while not it.IsDoneWithTraversal():
            leaf = it.GetCurrentDataObject()
            if leaf is not None:
                return leaf
            it.GoToNextItem()
        return None
    return data


class ArrayStats:
    """Component count and value range of one array over all time steps."""

    def __init__(self, components):
        self.components = components
        self.lo = math.inf
        self.hi = -math.inf
        self.yy = (math.inf, -math.inf)

    def add(self, lo, hi):
        self.lo, self.hi = min(self.lo, lo), max(self.hi, hi)


def array_values(array):
    """All values of a vtkDataArray as a flat list of floats (numpy when available)."""
    try:
        from vtkmodules.util.numpy_support import vtk_to_numpy

        return vtk_to_numpy(array).ravel().tolist()
    except ImportError:
        n = array.GetNumberOfTuples() * array.GetNumberOfComponents()
        return [array.GetValue(i) for i in range(n)]


def check_series(simple, pvd_path, label, wanted):
    """Checks one .pvd series; returns (reader, times, report lines)."""
    entries = read_collection(pvd_path)
    reader = simple.PVDReader(registrationName=label, FileName=pvd_path)
    times = reader.TimestepValues
    if isinstance(times, (int, float)):
        times = [times]
    times = list(times) if times is not None else []
    if len(times) == 0:
        # A single-step collection may report no time values; the XML still lists one.
        times = [entries[0][0]] if len(entries) == 1 else []
    if len(times) == 0:
        raise CheckError(f"{pvd_path}: ParaView reports no time steps")
    if len(times) != len(entries):
        raise CheckError(
            f"{pvd_path}: ParaView reports {len(times)} time steps, the file lists {len(entries)}"
        )

    stats = {"point": {}, "cell": {}}
    points_per_step, cells_per_step = [], []
    for t, (_, file_path) in zip(times, entries):
        reader.UpdatePipeline(t)
        data = first_leaf(simple.servermanager.Fetch(reader))
        where = f"{os.path.basename(file_path)} (t = {t:g})"
        if data is None:
            raise CheckError(f"{where}: ParaView read no data")
        n_points, n_cells = data.GetNumberOfPoints(), data.GetNumberOfCells()
        points_per_step.append(n_points)
        cells_per_step.append(n_cells)
        if n_points > 0:
            coords = array_values(data.GetPoints().GetData())
            bad = next((i for i, x in enumerate(coords) if not math.isfinite(x)), None)
            if bad is not None:
                raise CheckError(f"{where}: point {bad // 3} has a non-finite coordinate")
        for kind, attrs in (("point", data.GetPointData()), ("cell", data.GetCellData())):
            for a in range(attrs.GetNumberOfArrays()):
                array = attrs.GetArray(a)
                if array is None:
                    continue  # not a numeric array
                name, comps = array.GetName(), array.GetNumberOfComponents()
                values = array_values(array)
                bad = next((i for i, x in enumerate(values) if not math.isfinite(x)), None)
                if bad is not None:
                    raise CheckError(
                        f"{where}: {kind} array {name!r} has a non-finite value at index {bad} "
                        f"({kind} {bad // comps}, component {bad % comps})"
                    )
                s = stats[kind].setdefault(name, ArrayStats(comps))
                if s.components != comps:
                    raise CheckError(
                        f"{where}: {kind} array {name!r} has {comps} components, "
                        f"{s.components} in an earlier step"
                    )
                if values:
                    s.add(min(values), max(values))
                    if comps == 9:
                        yy = values[YY::9]
                        s.yy = (min(s.yy[0], min(yy)), max(s.yy[1], max(yy)))
        for name, expected in wanted:
            array = data.GetPointData().GetArray(name)
            if array is None:
                found = [
                    data.GetPointData().GetArrayName(i)
                    for i in range(data.GetPointData().GetNumberOfArrays())
                ]
                raise CheckError(f"{where}: no point array {name!r} (found {found})")
            comps = array.GetNumberOfComponents()
            if expected is not None and comps != expected:
                raise CheckError(
                    f"{where}: point array {name!r} has {comps} components, expected {expected}"
                )

    def span(values):
        lo, hi = min(values), max(values)
        return f"{lo}" if lo == hi else f"{lo}..{hi}"

    lines = [
        f"{label}: {pvd_path}",
        f"  time steps: {len(times)} (t = {times[0]:g} .. {times[-1]:g})",
        f"  points: {span(points_per_step)}, cells: {span(cells_per_step)}",
    ]
    for kind in ("point", "cell"):
        for name, s in stats[kind].items():
            rng = f"[{s.lo:.6g}, {s.hi:.6g}]" if s.lo <= s.hi else "(empty)"
            plural = "" if s.components == 1 else "s"
            line = f"  {kind} array {name}: {s.components} component{plural}, range {rng}"
            if s.components == 9 and s.yy[0] <= s.yy[1]:
                line += f", yy range [{s.yy[0]:.6g}, {s.yy[1]:.6g}]"
            lines.append(line)
    return reader, times, lines


def render_png(simple, out_dir, time, png_path):
    """Saves a picture of `time` as scripts/show_stress.py shows a run."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import show_stress

    view = show_stress.show(simple, out_dir, time=time)
    show_stress.save_picture(simple, view, png_path)


def parse_field(spec):
    name, sep, count = spec.partition(":")
    if sep:
        try:
            return name, int(count)
        except ValueError:
            raise argparse.ArgumentTypeError(f"bad component count in {spec!r}")
    return name, KNOWN_COMPONENTS.get(name)


def main(argv):
    parser = argparse.ArgumentParser(
        description="Check an impm output folder with ParaView (particles.pvd, grid.pvd)."
    )
    parser.add_argument("out_dir", help="output folder holding particles.pvd")
    parser.add_argument(
        "fields",
        nargs="*",
        type=parse_field,
        help="point arrays that must exist, as NAME or NAME:COMPONENTS",
    )
    parser.add_argument("--png", help="render the last step to this PNG file")
    parser.add_argument(
        "--nodes", nargs="+", type=parse_field, default=[], help="point arrays of nodes.pvd"
    )
    parser.add_argument(
        "--tractions",
        nargs="+",
        type=parse_field,
        default=[],
        help="point arrays of tractions.pvd",
    )
    parser.add_argument(
        "--pressure",
        nargs="+",
        type=parse_field,
        default=[],
        help="point arrays of pressure.pvd (the pressure's load points)",
    )
    parser.add_argument(
        "--times",
        type=lambda text: [float(t) for t in text.split(",")],
        help="expected time values (load factors) of particles.pvd, comma-separated",
    )
    args = parser.parse_args(argv)

    particles_pvd = os.path.join(args.out_dir, "particles.pvd")
    grid_pvd = os.path.join(args.out_dir, "grid.pvd")
    if not os.path.isfile(particles_pvd):
        print(f"FAIL: {particles_pvd} does not exist", file=sys.stderr)
        return 1
    try:
        from paraview import simple
    except ImportError as e:
        print(f"FAIL: cannot import paraview.simple ({e}); run with pvpython", file=sys.stderr)
        return 2

    try:
        particles, times, report = check_series(simple, particles_pvd, "particles", args.fields)
        if args.times is not None:
            if len(times) != len(args.times) or any(
                abs(a - b) > 1e-12 for a, b in zip(times, args.times)
            ):
                raise CheckError(f"particles.pvd times are {list(times)}, expected {args.times}")
        if os.path.isfile(grid_pvd):
            report += check_series(simple, grid_pvd, "grid", [])[2]
        for series, wanted in (
            ("nodes", args.nodes),
            ("tractions", args.tractions),
            ("pressure", args.pressure),
        ):
            path = os.path.join(args.out_dir, f"{series}.pvd")
            if os.path.isfile(path):
                report += check_series(simple, path, series, wanted)[2]
            elif wanted:
                raise CheckError(f"{path} does not exist")
        print("\n".join(report))
        for series, wanted in (
            ("particles", args.fields),
            ("nodes", args.nodes),
            ("tractions", args.tractions),
            ("pressure", args.pressure),
        ):
            for name, expected in wanted:
                note = "" if expected is None else f" (expected {expected})"
                print(f"  required {series} point array {name}: present{note}")
        if args.times is not None:
            print(f"  particles.pvd times: {args.times}")
        if args.png:
            if not any(name == "cauchy_stress" for name, _ in args.fields):
                data = first_leaf(simple.servermanager.Fetch(particles))
                if data is None or data.GetPointData().GetArray("cauchy_stress") is None:
                    raise CheckError("--png needs a point array cauchy_stress")
            render_png(simple, args.out_dir, times[-1], args.png)
            if not os.path.isfile(args.png) or os.path.getsize(args.png) == 0:
                raise CheckError(f"no picture was written to {args.png}")
            print(f"  picture: {args.png} (t = {times[-1]:g}, coloured by the vertical stress)")
    except CheckError as e:
        print(f"FAIL: {e}", file=sys.stderr)
        return 1
    print("OK")
    return 0


if __name__ == "__main__":
    status = main(sys.argv[1:])
    # Skip the interpreter's teardown: under xvfb-run, VTK's X/GLX cleanup sometimes fails after
    # a picture is saved and would turn success into a non-zero exit status.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
