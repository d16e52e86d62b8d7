#!/usr/bin/env python3
"""Writes the example mesh files of scenes/meshes/ with VTK's own writers.

Run once, with VTK installed outside the repository:

    python3 -m venv /tmp/vtk-venv && /tmp/vtk-venv/bin/pip install vtk
    /tmp/vtk-venv/bin/python scripts/make-examples.py scenes/meshes

Each file is small (a few thousand triangles) and is committed; this script says how it was made.
"""

import sys
from pathlib import Path

import vtk


def clean_triangles(source):
    """Triangles only, points merged, normals dropped (dcrt computes its own)."""
    tri = vtk.vtkTriangleFilter()
    tri.SetInputConnection(source.GetOutputPort())
    clean = vtk.vtkCleanPolyData()
    clean.SetInputConnection(tri.GetOutputPort())
    clean.Update()
    return clean.GetOutput()


def torus():
    """A superquadric torus: the STL example (a CAD-like part)."""
    s = vtk.vtkSuperquadricSource()
    s.SetToroidal(1)
    s.SetThetaResolution(32)
    s.SetPhiResolution(16)
    s.SetThickness(0.35)
    s.SetPhiRoundness(0.4)
    s.SetThetaRoundness(0.4)
    s.SetSize(1.0)
    return clean_triangles(s)


def write_stl(poly, path):
    w = vtk.vtkSTLWriter()
    w.SetInputData(poly)
    w.SetFileTypeToBinary()
    w.SetHeader("dcrt example: a superquadric torus written by vtkSTLWriter")
    w.SetFileName(str(path))
    w.Write()


def isosurface():
    """ParaView's classic: the Wavelet source, contoured at RTData = 160, plus a second field
    ("pressure", a smooth function of position) to colour it by, as a simulation's isosurface
    coloured by another variable would be."""
    wavelet = vtk.vtkRTAnalyticSource()
    wavelet.SetWholeExtent(-10, 10, -10, 10, -10, 10)
    contour = vtk.vtkContourFilter()
    contour.SetInputConnection(wavelet.GetOutputPort())
    contour.SetValue(0, 160.0)
    contour.ComputeNormalsOff()
    contour.ComputeScalarsOn()
    calc = vtk.vtkArrayCalculator()
    calc.SetInputConnection(contour.GetOutputPort())
    calc.AddCoordinateScalarVariable("x", 0)
    calc.AddCoordinateScalarVariable("y", 1)
    calc.AddCoordinateScalarVariable("z", 2)
    calc.SetFunction("101325 + 40 * (x * x - y * y) + 300 * sin(z / 3)")
    calc.SetResultArrayName("pressure")
    calc.Update()
    return calc.GetOutput()


def bracket():
    """A block with a bore and a boss (cube, cylinder), each face tagged with a cell array
    "region" (0 the block, 1 the boss): the legacy VTK example, coloured by cell data."""
    parts = vtk.vtkAppendPolyData()
    for i, src in enumerate([vtk.vtkCubeSource(), vtk.vtkCylinderSource()]):
        if i == 0:
            src.SetXLength(2.0)
            src.SetYLength(1.0)
            src.SetZLength(0.6)
        else:
            src.SetRadius(0.35)
            src.SetHeight(0.8)
            src.SetResolution(24)
            src.SetCenter(0.5, 0.6, 0.0)
        tri = clean_triangles(src)
        region = vtk.vtkIntArray()
        region.SetName("region")
        for _ in range(tri.GetNumberOfCells()):
            region.InsertNextValue(i)
        tri.GetCellData().AddArray(region)
        tri.GetPointData().Initialize()
        parts.AddInputData(tri)
    parts.Update()
    return parts.GetOutput()


def write_vtp(poly, path):
    """As ParaView saves .vtp by default: appended raw data, zlib-compressed."""
    w = vtk.vtkXMLPolyDataWriter()
    w.SetInputData(poly)
    w.SetDataModeToAppended()
    w.EncodeAppendedDataOff()
    w.SetCompressorTypeToZLib()
    w.SetFileName(str(path))
    w.Write()


def write_vtk(poly, path):
    w = vtk.vtkPolyDataWriter()
    w.SetInputData(poly)
    w.SetFileTypeToASCII()
    w.SetFileName(str(path))
    w.Write()


def write_parts_gltf(path):
    """Three coloured parts, each an actor with its own position: exported by VTK's
    vtkGLTFExporter as nodes with transforms and materials with base colours (one file, the
    buffers inlined as data URIs)."""
    ren = vtk.vtkRenderer()
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.AddRenderer(ren)
    specs = [
        (vtk.vtkCubeSource(), (0.0, 0.0, 0.0), (0.80, 0.80, 0.82)),
        (vtk.vtkCylinderSource(), (1.2, 0.0, 0.0), (0.90, 0.45, 0.10)),
        (vtk.vtkSphereSource(), (-1.2, 0.0, 0.0), (0.15, 0.35, 0.80)),
    ]
    for src, pos, color in specs:
        if isinstance(src, vtk.vtkCylinderSource):
            src.SetResolution(24)
        if isinstance(src, vtk.vtkSphereSource):
            src.SetThetaResolution(24)
            src.SetPhiResolution(12)
        mapper = vtk.vtkPolyDataMapper()
        mapper.SetInputData(clean_triangles(src))
        actor = vtk.vtkActor()
        actor.SetMapper(mapper)
        actor.SetPosition(*pos)
        actor.GetProperty().SetColor(*color)
        ren.AddActor(actor)
    exporter = vtk.vtkGLTFExporter()
    exporter.SetRenderWindow(win)
    exporter.InlineDataOn()
    exporter.SetFileName(str(path))
    exporter.Write()


def main():
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "scenes/meshes")
    out.mkdir(parents=True, exist_ok=True)
    write_stl(torus(), out / "torus.stl")
    write_vtp(isosurface(), out / "isosurface.vtp")
    write_vtk(bracket(), out / "bracket.vtk")
    write_parts_gltf(out / "parts.gltf")


if __name__ == "__main__":
    main()
