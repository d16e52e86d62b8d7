#!/usr/bin/env python3
"""Writes tests/data/vtk/: one small dataset in every form VTK's writers produce, for the
loaders' tests (the same geometry and arrays in each file).

    python3 -m venv /tmp/vtk-venv && /tmp/vtk-venv/bin/pip install vtk
    /tmp/vtk-venv/bin/python scripts/make-vtk-fixtures.py tests/data/vtk
"""

import sys
from pathlib import Path

import vtk


def dataset():
    """7 points; cells: a vertex, a line, a triangle, a quad and a 4-point strip."""
    pts = vtk.vtkPoints()
    for p in [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0.5), (2, 1, 0.5), (0.5, 0.5, 1)]:
        pts.InsertNextPoint(p)
    pd = vtk.vtkPolyData()
    pd.SetPoints(pts)
    verts, lines, polys, strips = (vtk.vtkCellArray() for _ in range(4))
    verts.InsertNextCell(1, [6])
    lines.InsertNextCell(2, [0, 6])
    polys.InsertNextCell(3, [0, 1, 6])
    polys.InsertNextCell(4, [0, 1, 2, 3])
    strips.InsertNextCell(4, [1, 4, 2, 5])
    pd.SetVerts(verts)
    pd.SetLines(lines)
    pd.SetPolys(polys)
    pd.SetStrips(strips)
    t = vtk.vtkDoubleArray()
    t.SetName("temperature")
    for i in range(7):
        t.InsertNextValue(300 + 10 * i)
    v = vtk.vtkFloatArray()
    v.SetName("velocity")
    v.SetNumberOfComponents(3)
    for i in range(7):
        v.InsertNextTuple3(i, 0, 1)
    c = vtk.vtkUnsignedCharArray()
    c.SetName("rgb")
    c.SetNumberOfComponents(3)
    for i in range(7):
        c.InsertNextTuple3(40 * i, 255 - 40 * i, 128)
    for a in (t, v, c):
        pd.GetPointData().AddArray(a)
    r = vtk.vtkIntArray()
    r.SetName("region")
    a = vtk.vtkFloatArray()
    a.SetName("area")
    for i in range(5):
        r.InsertNextValue(i + 1)
        a.InsertNextValue(0.25 * i)
    pd.GetCellData().AddArray(r)
    pd.GetCellData().AddArray(a)
    return pd


def grid(pd):
    g = vtk.vtkAppendFilter()
    g.SetInputData(pd)
    g.Update()
    return g.GetOutput()


def main():
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "tests/data/vtk")
    out.mkdir(parents=True, exist_ok=True)
    pd = dataset()
    for version, tag in [(42, "v42"), (51, "v51")]:
        for binary in (False, True):
            for data, writer, kind in [(pd, vtk.vtkPolyDataWriter(), "poly"),
                                       (grid(pd), vtk.vtkUnstructuredGridWriter(), "grid")]:
                writer.SetInputData(data)
                writer.SetFileVersion(version)
                if binary:
                    writer.SetFileTypeToBinary()
                else:
                    writer.SetFileTypeToASCII()
                name = f"{kind}-{tag}-{'binary' if binary else 'ascii'}.vtk"
                writer.SetFileName(str(out / name))
                writer.Write()
    modes = [("ascii", None, 32), ("binary", None, 32), ("binary", "zlib", 64),
             ("appended", None, 64), ("appended", "zlib", 32), ("base64", "zlib", 64),
             ("base64", None, 32)]
    for mode, comp, header in modes:
        w = vtk.vtkXMLPolyDataWriter()
        w.SetInputData(pd)
        if mode == "ascii":
            w.SetDataModeToAscii()
        elif mode == "binary":
            w.SetDataModeToBinary()
        else:
            w.SetDataModeToAppended()
            w.SetEncodeAppendedData(mode == "base64")
        if comp:
            w.SetCompressorTypeToZLib()
            w.SetBlockSize(40)  # several compressed blocks per array
        else:
            w.SetCompressorTypeToNone()
        w.SetHeaderType(header)
        w.SetFileName(str(out / f"poly-{mode}-{comp or 'raw'}-{header}.vtp"))
        w.Write()


if __name__ == "__main__":
    main()
