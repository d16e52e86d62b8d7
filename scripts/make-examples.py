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


def main():
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "scenes/meshes")
    out.mkdir(parents=True, exist_ok=True)
    write_stl(torus(), out / "torus.stl")


if __name__ == "__main__":
    main()
