//! Tests of `legacy`.

use super::*;

/// A unit square as two polygons and a strip, point and cell data of several kinds.
pub const ASCII: &str = "# vtk DataFile Version 3.0\nsquare\nASCII\nDATASET POLYDATA\n\
    POINTS 5 float\n0 0 0 1 0 0 1 1 0\n0 1 0 0.5 0.5 1\n\
    VERTICES 1 2\n1 4\n\
    POLYGONS 2 8\n3 0 1 4\n3 1 2 4\n\
    TRIANGLE_STRIPS 1 5\n4 2 3 4 0\n\
    POINT_DATA 5\nSCALARS pressure float 1\nLOOKUP_TABLE default\n0 1 2 3 4\n\
    FIELD FieldData 1\nvel%20ocity 3 5 double\n1 0 0 0 1 0 0 0 1 1 1 1 2 0 0\n\
    CELL_DATA 4\nCOLOR_SCALARS rgb 3\n1 0 0 0 1 0 0 0 1 1 1 1\n\
    SCALARS id int\nLOOKUP_TABLE default\n7 8 9 10\n";

pub fn parse(bytes: &[u8], keep: &Keep) -> Result<(Mesh, MeshData)> {
    parse_vtk(bytes, Path::new("t.vtk"), keep)
}

fn assert_err(bytes: &[u8], place: &str, what: &str) {
    let e = parse(bytes, &Keep::All).expect_err(what).to_string();
    assert!(
        e.contains("t.vtk") && e.contains(place) && e.contains(what),
        "{e}"
    );
}

/// The same square written binary, big endian, by hand.
fn binary_of() -> Vec<u8> {
    let mut b =
        b"# vtk DataFile Version 3.0\nsquare\nBINARY\nDATASET POLYDATA\nPOINTS 5 float\n".to_vec();
    for v in [
        0f32, 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0., 0.5, 0.5, 1.,
    ] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nVERTICES 1 2\n");
    for v in [1i32, 4] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nPOLYGONS 2 8\n");
    for v in [3i32, 0, 1, 4, 3, 1, 2, 4] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nTRIANGLE_STRIPS 1 5\n");
    for v in [4i32, 2, 3, 4, 0] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nPOINT_DATA 5\nSCALARS pressure float 1\nLOOKUP_TABLE default\n");
    for v in [0f32, 1., 2., 3., 4.] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nFIELD FieldData 1\nvel%20ocity 3 5 double\n");
    for v in [1f64, 0., 0., 0., 1., 0., 0., 0., 1., 1., 1., 1., 2., 0., 0.] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.extend_from_slice(b"\nCELL_DATA 4\nCOLOR_SCALARS rgb 3\n");
    b.extend_from_slice(&[255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255]);
    b.extend_from_slice(b"\nSCALARS id int\nLOOKUP_TABLE default\n");
    for v in [7i32, 8, 9, 10] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b.push(b'\n');
    b
}

#[test]
fn ascii_and_binary_polydata() {
    for (binary, bytes) in [(false, ASCII.as_bytes().to_vec()), (true, binary_of())] {
        let (m, d) = parse(&bytes, &Keep::All).unwrap();
        assert_eq!(m.positions.len(), 5);
        // Polygons first (cells 1, 2), then the strip (cell 3): cell 0 is the vertex.
        assert_eq!(
            m.triangles,
            vec![[0, 1, 4], [1, 2, 4], [2, 3, 4], [4, 3, 0]]
        );
        assert_eq!(d.triangle_cells, vec![1, 2, 3, 3]);
        let names: Vec<String> = d.arrays.iter().map(|a| a.to_string()).collect();
        assert_eq!(
            names,
            [
                "pressure (point data, 1 x float32)",
                "vel ocity (point data, 3 x float64)",
                if binary {
                    "rgb (cell data, 3 x uint8, colours)"
                } else {
                    "rgb (cell data, 3 x float32, colours)"
                },
                "id (cell data, 1 x int32)",
            ]
        );
        assert_eq!(d.values(0).unwrap().data, vec![0.0, 1.0, 2.0, 3.0, 4.0]);
        assert_eq!(d.values(2).unwrap().data[..3], [1.0, 0.0, 0.0]);
        assert_eq!(d.values(3).unwrap().data, vec![7.0, 8.0, 9.0, 10.0]);
    }
    // Only what is asked for is kept.
    let keep = Keep::One {
        name: "id".into(),
        assoc: Assoc::Cell,
    };
    let (_, d) = parse(ASCII.as_bytes(), &keep).unwrap();
    assert_eq!(d.kept.len(), 1);
    assert_eq!(d.arrays.len(), 4);
    let (_, d) = parse(ASCII.as_bytes(), &Keep::None).unwrap();
    assert!(d.kept.is_empty() && d.triangle_cells.is_empty());
}

#[test]
fn version_5_cells_and_grids() {
    let v5 = "# vtk DataFile Version 5.1\nv5\nASCII\nDATASET POLYDATA\nPOINTS 4 double\n\
        0 0 0 1 0 0 1 1 0 0 1 0\nMETADATA\nINFORMATION 0\n\n\
        POLYGONS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n0 1 2 3\n";
    let (m, _) = parse(v5.as_bytes(), &Keep::None).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    let grid = "# vtk DataFile Version 4.2\ng\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n\
        0 0 0 1 0 0 1 1 0 0 1 0\nCELLS 3 11\n3 0 1 2\n2 0 2\n3 0 2 3\nCELL_TYPES 3\n5 3 5\n\
        CELL_DATA 3\nSCALARS c float\nLOOKUP_TABLE default\n1 2 3\n";
    let (m, d) = parse(grid.as_bytes(), &Keep::All).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(d.triangle_cells, vec![0, 2]);
    let tet = grid.replace("CELL_TYPES 3\n5 3 5", "CELL_TYPES 3\n5 3 10");
    assert_err(
        tet.as_bytes(),
        "CELLS: cell 2",
        "tetrahedron (a volume cell)",
    );
}

#[test]
fn errors_name_the_element_and_line() {
    let edit = |from: &str, to: &str| ASCII.replacen(from, to, 1).into_bytes();
    assert_err(b"hello\n", "line 1", "not a legacy VTK file");
    assert_err(
        &edit("ASCII\n", "TEXT\n"),
        "line 3",
        "expected ASCII or BINARY",
    );
    assert_err(
        &edit("POLYDATA", "STRUCTURED_POINTS"),
        "line 4",
        "dcrt reads POLYDATA",
    );
    assert_err(
        &edit("0 1 0 0.5", "0 nan 0 0.5"),
        "POINTS: point 3 (line 7)",
        "not finite",
    );
    assert_err(
        &edit("0 1 0 0.5", "0 x 0 0.5"),
        "POINTS: point 3 (line 7)",
        "found 'x'",
    );
    assert_err(
        &edit("3 1 2 4", "3 1 2 5"),
        "POLYGONS: cell 1",
        "point index 5 out of range (5 points)",
    );
    assert_err(
        &edit("3 1 2 4", "3 1 -2 4"),
        "POLYGONS: cell 1",
        "point index -2",
    );
    assert_err(
        &edit("POLYGONS 2 8", "POLYGONS 3 8"),
        "",
        "holds 2 whole cells, the header says 3",
    );
    assert_err(
        &edit("POLYGONS 2 8", "POLYGONS 2 7"),
        "",
        "ends inside cell 1: 1 point ids short",
    );
    assert_err(
        &edit("POINT_DATA 5", "POINT_DATA 6"),
        "line 15",
        "POINT_DATA 6, but the dataset has 5 points",
    );
    assert_err(
        &edit("CELL_DATA 4", "CELL_DATA 3"),
        "",
        "CELL_DATA 3, but the dataset has 4 cells",
    );
    assert_err(
        &edit("0 1 2 3 4\n", "0 1 2 3\n"),
        "point 'pressure'",
        "expected a float32 value, found 'FIELD'",
    );
    assert_err(
        &edit("vel%20ocity 3 5", "vel%20ocity 3 4"),
        "",
        "has 4 tuples, the point data has 5",
    );
    assert_err(
        &edit("SCALARS id int", "SCALARS id string"),
        "",
        "unknown value type 'string'",
    );
    assert_err(
        &edit(
            "SCALARS id int\nLOOKUP_TABLE",
            "SCALARS id int\nLOOKUPTABLE",
        ),
        "",
        "expected LOOKUP_TABLE",
    );
    assert_err(
        &edit("7 8 9 10", "7 8 9 1e3"),
        "cell 'id': cell 3",
        "expected a int32 value",
    );
    assert_err(
        &edit("CELL_DATA", "CELL_DATUM"),
        "",
        "unexpected 'CELL_DATUM'",
    );
    let cut = ASCII.find("3 1 2 4").unwrap();
    assert_err(
        &ASCII.as_bytes()[..cut],
        "POLYGONS: integer 4 of 8",
        "file ends after 4 of 8",
    );
    let bin = binary_of();
    assert_err(&bin[..100], "POINTS: point", "file ends after");
    let mut bad = bin.clone();
    let at = bin.windows(8).position(|w| w == b"POLYGONS").unwrap() + 13 + 4 * 7;
    bad[at..at + 4].copy_from_slice(&9i32.to_be_bytes());
    assert_err(&bad, "POLYGONS: cell 1", "point index 9");
}

#[test]
fn random_input_never_panics() {
    let mut seed = 0x1234_5678_9abc_def1u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let valid = [ASCII.as_bytes().to_vec(), binary_of()];
    for round in 0..3000 {
        let mut b = valid[round % 2].clone();
        for _ in 0..1 + next() % 4 {
            let i = next() as usize % b.len();
            b[i] = match next() % 3 {
                0 => next() as u8,
                1 => b"0123456789 \n-."[next() as usize % 14],
                _ => b[i].wrapping_add(1),
            };
        }
        if next() % 3 == 0 {
            b.truncate(next() as usize % (b.len() + 1));
        }
        if let Ok((m, _)) = parse(&b, &Keep::All) {
            m.validate(Path::new("fuzz.vtk")).unwrap();
        }
    }
}
