"""Open an impm run in ParaView and colour the material points by the vertical stress.

Usage:
    xvfb-run -a pvpython scripts/show_stress.py OUT_DIR [--png FILE] [--time T]
    IMPM_OUT=OUT_DIR paraview --script=scripts/show_stress.py

The first form saves a picture (the last output step unless --time T, a load factor); the
second opens the ParaView GUI with the same pipeline, ready to play through the load steps
(the .pvd time is the load factor).

"Vertical" is the last axis of the run's dimension, read from OUT_DIR/summary.json: sigma_xx
in 1D, sigma_yy in 2D, sigma_zz in 3D, i.e. component 0, 4 or 8 of the row-major 3x3
`cauchy_stress` array. Also shown: the background grid (grid.pvd) as a wireframe and, when
the scene has them, the traction points (tractions.pvd) with arrows of their forces and the
points carrying point loads with arrows of `point_load`.

scripts/check_output.py --png uses show() from here.
"""

import json
import os
import sys


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


def show(simple, out_dir, view=None, time=None):
    """Builds the pipeline in `view` (a new render view if None) and returns the view."""
    particles_pvd = os.path.join(out_dir, "particles.pvd")
    if not os.path.isfile(particles_pvd):
        raise FileNotFoundError(f"{particles_pvd} does not exist")
    component, label = vertical_component(out_dir)
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

    p = simple.Show(particles, view)
    p.SetRepresentationType("Points")
    p.PointSize = 10
    try:
        p.RenderPointsAsSpheres = 1
    except AttributeError:
        pass
    simple.ColorBy(p, ("POINTS", "cauchy_stress"))
    lut = simple.GetColorTransferFunction("cauchy_stress")
    lut.VectorMode = "Component"
    lut.VectorComponent = component
    p.RescaleTransferFunctionToDataRange(False, True)
    p.SetScalarBarVisibility(view, True)
    bar = simple.GetScalarBar(lut, view)
    bar.Title = f"cauchy_stress {label} (vertical)"
    bar.ComponentTitle = ""
    bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
    bar.WindowLocation = "Upper Right Corner"
    bar.ScalarBarLength = 0.4
    bar.TitleFontSize = bar.LabelFontSize = 12
    bar.ScalarBarThickness = 12
    bounds = particles.GetDataInformation().GetBounds()
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
    args = parser.parse_args(argv)
    if not args.out_dir:
        print("give OUT_DIR (or set IMPM_OUT)", file=sys.stderr)
        return 2
    from paraview import simple

    try:
        view = show(simple, args.out_dir, time=args.time)
    except FileNotFoundError as e:
        print(f"FAIL: {e}", file=sys.stderr)
        return 1
    if args.png:
        time = view.ViewTime
        save_picture(simple, view, args.png)
        if not os.path.isfile(args.png) or os.path.getsize(args.png) == 0:
            print(f"FAIL: no picture was written to {args.png}", file=sys.stderr)
            return 1
        print(f"picture: {args.png} (t = {time:g})")
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
