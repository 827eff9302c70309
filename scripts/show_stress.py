"""Open an impm run in ParaView and colour the material points by a stress component.

Usage:
    xvfb-run -a pvpython scripts/show_stress.py OUT_DIR [--png FILE] [--time T]
        [--component C] [--warp FACTOR]
    IMPM_OUT=OUT_DIR paraview --script=scripts/show_stress.py

The first form saves a picture (the last output step unless --time T, a load factor); the
second opens the ParaView GUI with the same pipeline, ready to play through the load steps
(the .pvd time is the load factor).

"Vertical" is the last axis of the run's dimension, read from OUT_DIR/summary.json: sigma_xx
in 1D, sigma_yy in 2D, sigma_zz in 3D, i.e. component 0, 4 or 8 of the row-major 3x3
`cauchy_stress` array. `--component` picks another: one of the nine (XX, XY, XZ, YX, YY, YZ, ZX,
ZY, ZZ; the `.vtu` names them so), `von_mises` (sqrt(3/2 s:s), s the deviator) or `mean`
((XX + YY + ZZ) / 3). The colour map suits the values shown: diverging (blue - white - red,
symmetric about zero) when they take both signs, sequential (viridis) when they are of one
sign. `--warp FACTOR` draws the points at X + FACTOR u (reference position plus FACTOR times
the displacement): 1 is the deformed body (the default, as written), 0 the reference one,
larger factors magnify small displacements. Also shown: the background grid (grid.pvd) as a wireframe and, when
the scene has them, the traction points (tractions.pvd) with arrows of their forces and the
points carrying point loads with arrows of `point_load`.

scripts/check_output.py --png uses show() from here.
"""

import json
import os
import sys


# what the last show() drew: its colour map ("diverging" or "sequential") and value range
SHOWN = {}

COMPONENTS = ["XX", "XY", "XZ", "YX", "YY", "YZ", "ZX", "ZY", "ZZ"]



def _s(index):
    """Component `index` (row-major) of cauchy_stress in ParaView's PythonCalculator, which
    sees a 9-component array as n 3 x 3 tensors."""
    return f"cauchy_stress[:,{index // 3},{index % 3}]"


# numpy expressions for ParaView's PythonCalculator
DERIVED = {
    "mean": f"({_s(0)} + {_s(4)} + {_s(8)}) / 3.0",
    "von_mises": f"sqrt(0.5 * (({_s(0)} - {_s(4)})**2"
    f" + ({_s(4)} - {_s(8)})**2"
    f" + ({_s(8)} - {_s(0)})**2)"
    f" + 3.0 * ({_s(1)}**2 + {_s(5)}**2 + {_s(2)}**2))",
}


def quantity(out_dir, component):
    """(numpy expression, label) of the quantity to colour by: `component` is None (the
    vertical normal stress), one of COMPONENTS (any case) or one of DERIVED."""
    if component is None:
        index, label = vertical_component(out_dir)
        return _s(index), f"cauchy_stress {label} (vertical)"
    word = component.strip()
    if word.lower() in DERIVED:
        return DERIVED[word.lower()], word.lower().replace("_", " ") + " stress"
    if word.upper() in COMPONENTS:
        return _s(COMPONENTS.index(word.upper())), f"cauchy_stress {word.upper()}"
    raise ValueError(
        f"--component {component!r}: give one of {', '.join(COMPONENTS)}, "
        + ", ".join(sorted(DERIVED))
    )


def colour_map(lut, low, high):
    """Diverging map symmetric about zero for values of both signs, sequential otherwise."""
    if low < 0.0 < high:
        lut.ApplyPreset("Cool to Warm", True)
        largest = max(-low, high)
        lut.RescaleTransferFunction(-largest, largest)
        return "diverging"
    lut.ApplyPreset("Viridis (matplotlib)", True)
    if high <= low:
        high = low + max(abs(low), 1.0) * 1e-9
    lut.RescaleTransferFunction(low, high)
    return "sequential"


def vertical_component(out_dir):
    """Row-major index of the vertical normal stress for the run's dimension (summary.json)."""
    try:
        with open(os.path.join(out_dir, "summary.json")) as f:
            dimension = int(json.load(f)["dimension"])
    except (OSError, ValueError, KeyError, TypeError):
        dimension = 2
    axis = max(0, min(dimension, 3) - 1)
    return 4 * axis, "xyz"[axis] * 2


def _arrows(simple, source, array, view, colour, length):
    """Arrows of a 3-component point array, the largest `length` long."""
    glyph = simple.Glyph(Input=source, GlyphType="Arrow")
    glyph.OrientationArray = ["POINTS", array]
    glyph.ScaleArray = ["POINTS", array]
    glyph.GlyphMode = "All Points"
    largest = max(abs(x) for x in source.PointData[array].GetRange(-1))
    glyph.ScaleFactor = length / largest if largest > 0 else 1.0
    display = simple.Show(glyph, view)
    display.ColorArrayName = ["POINTS", ""]
    display.AmbientColor = display.DiffuseColor = colour
    return glyph


def show(simple, out_dir, view=None, time=None, component=None, warp=None):
    """Builds the pipeline in `view` (a new render view if None) and returns the view.
    `component`: what to colour by (see quantity()); `warp`: draw the points at X + warp u."""
    particles_pvd = os.path.join(out_dir, "particles.pvd")
    if not os.path.isfile(particles_pvd):
        raise FileNotFoundError(f"{particles_pvd} does not exist")
    expression, label = quantity(out_dir, component)
    if view is None:
        view = simple.CreateView("RenderView")
    view.OrientationAxesVisibility = 1
    view.Background = [1.0, 1.0, 1.0]
    try:
        view.UseColorPaletteForBackground = 0  # ParaView >= 5.10
    except AttributeError:
        pass

    particles = simple.PVDReader(registrationName="particles", FileName=particles_pvd)
    times = particles.TimestepValues
    if isinstance(times, (int, float)):
        times = [times]
    times = list(times or [0.0])
    view.ViewTime = times[-1] if time is None else time

    grid_pvd = os.path.join(out_dir, "grid.pvd")
    if os.path.isfile(grid_pvd):
        grid = simple.PVDReader(registrationName="grid", FileName=grid_pvd)
        g = simple.Show(grid, view)
        g.SetRepresentationType("Wireframe")
        g.ColorArrayName = ["POINTS", ""]
        g.AmbientColor = g.DiffuseColor = [0.6, 0.6, 0.6]

    source = particles
    if warp is not None:
        source = simple.Calculator(registrationName="warped", Input=particles)
        source.CoordinateResults = 1
        source.Function = f"reference_position + {float(warp)!r} * displacement"
        label += f", warp {warp:g}"
    source = simple.PythonCalculator(registrationName="shown", Input=source)
    source.Expression = expression
    source.ArrayName = "shown"

    p = simple.Show(source, view)
    p.SetRepresentationType("Points")
    p.PointSize = 10
    try:
        p.RenderPointsAsSpheres = 1
    except AttributeError:
        pass
    simple.ColorBy(p, ("POINTS", "shown"))
    lut = simple.GetColorTransferFunction("shown")
    source.UpdatePipeline(view.ViewTime)
    low, high = source.PointData["shown"].GetRange()
    SHOWN["colour map"] = colour_map(lut, low, high)
    SHOWN["range"] = (low, high)
    p.SetScalarBarVisibility(view, True)
    bar = simple.GetScalarBar(lut, view)
    bar.Title = label
    bar.ComponentTitle = ""
    bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
    bar.WindowLocation = "Upper Right Corner"
    bar.ScalarBarLength = 0.4
    bar.TitleFontSize = bar.LabelFontSize = 12
    bar.ScalarBarThickness = 12
    bounds = source.GetDataInformation().GetBounds()
    size = max(bounds[1] - bounds[0], bounds[3] - bounds[2], bounds[5] - bounds[4], 1e-12)

    data = simple.servermanager.Fetch(particles)
    leaf = data.GetBlock(0) if data is not None and data.IsA("vtkMultiBlockDataSet") else data
    if leaf is not None and leaf.GetPointData().GetArray("point_load") is not None:
        _arrows(simple, particles, "point_load", view, [0.8, 0.0, 0.8], 0.15 * size)

    tractions_pvd = os.path.join(out_dir, "tractions.pvd")
    if os.path.isfile(tractions_pvd):
        tractions = simple.PVDReader(registrationName="tractions", FileName=tractions_pvd)
        t = simple.Show(tractions, view)
        t.SetRepresentationType("Points")
        t.PointSize = 6
        t.ColorArrayName = ["POINTS", ""]
        t.AmbientColor = t.DiffuseColor = [0.0, 0.0, 0.0]
        _arrows(simple, tractions, "force", view, [0.1, 0.1, 0.1], 0.1 * size)

    view.ResetCamera()
    simple.GetActiveCamera().Dolly(0.8)
    return view


def save_picture(simple, view, png_path):
    """Renders `view` to a 1200 x 800 PNG, then releases the view: deleting it while the X
    display still exists avoids a "GLXBadContext" error (and a non-zero exit status) when
    pvpython exits under xvfb-run."""
    view.ViewSize = [1200, 800]
    simple.Render(view)
    simple.SaveScreenshot(
        png_path, view, ImageResolution=[1200, 800], FontScaling="Do not scale fonts"
    )
    simple.Delete(view)


def main(argv):
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", default=os.environ.get("IMPM_OUT"))
    parser.add_argument("--png", help="save a picture to this file")
    parser.add_argument("--time", type=float, help="load factor to show (default: the last)")
    parser.add_argument(
        "--component",
        help="XX, XY, .., ZZ, von_mises or mean (default: the vertical normal stress)",
    )
    parser.add_argument(
        "--warp",
        type=float,
        help="draw the points at X + WARP u (default: the deformed body, WARP = 1)",
    )
    args = parser.parse_args(argv)
    if not args.out_dir:
        print("give OUT_DIR (or set IMPM_OUT)", file=sys.stderr)
        return 2
    from paraview import simple

    try:
        view = show(
            simple, args.out_dir, time=args.time, component=args.component, warp=args.warp
        )
    except (FileNotFoundError, ValueError) as e:
        print(f"FAIL: {e}", file=sys.stderr)
        return 1
    if args.png:
        time = view.ViewTime
        save_picture(simple, view, args.png)
        if not os.path.isfile(args.png) or os.path.getsize(args.png) == 0:
            print(f"FAIL: no picture was written to {args.png}", file=sys.stderr)
            return 1
        low, high = SHOWN["range"]
        print(
            f"picture: {args.png} (t = {time:g}, values {low:g} .. {high:g},"
            f" {SHOWN['colour map']} colour map)"
        )
    else:
        simple.Render(view)
    return 0


if __name__ == "__main__":
    # In the GUI (paraview --script=...) the pipeline stays open; in pvpython the exit status
    # tells whether it worked.
    status = main(sys.argv[1:] if os.environ.get("IMPM_OUT") is None else [])
    if "paraview" not in os.path.basename(sys.executable):
        # Skip the interpreter's teardown: under xvfb-run, VTK's X/GLX cleanup sometimes fails
        # after the picture is saved and would turn success into a non-zero exit status.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
