//! Tests of `xml`.

use super::*;

/// The unit square of `vtkPlaneSource` with a point array `p`, as vtkXMLPolyDataWriter
/// writes it in ascii.
pub const ASCII: &str = r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian" header_type="UInt32">
  <PolyData>
<Piece NumberOfPoints="4" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="1" NumberOfPolys="1">
  <PointData>
    <DataArray type="Float32" Name="p" format="ascii" RangeMin="0" RangeMax="4.5">
      0 1.5 3 4.5
      <InformationKey name="L2_NORM_RANGE" location="vtkDataArray" length="2">
        <Value index="0">7</Value>
      </InformationKey>
    </DataArray>
  </PointData>
  <CellData>
    <DataArray type="UInt8" Name="rgb" NumberOfComponents="3" format="ascii">
      255 0 0 0 0 255
    </DataArray>
  </CellData>
  <Points>
    <DataArray type="Float32" Name="Points" NumberOfComponents="3" format="ascii">
      -0.5 -0.5 0 0.5 -0.5 0
      -0.5 0.5 0 0.5 0.5 0
    </DataArray>
  </Points>
  <Strips>
    <DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3</DataArray>
    <DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>
  </Strips>
  <Polys>
    <DataArray type="Int64" Name="connectivity" format="ascii">0 1 3 2</DataArray>
    <DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>
  </Polys>
</Piece>
  </PolyData>
</VTKFile>
"#;

pub fn parse(bytes: &[u8]) -> Result<(Mesh, MeshData)> {
    parse_vtp(bytes, Path::new("t.vtp"), &Keep::All)
}

fn assert_err(bytes: &[u8], place: &str, what: &str) {
    let e = parse(bytes).expect_err(what).to_string();
    assert!(
        e.contains("t.vtp") && e.contains(place) && e.contains(what),
        "{e}"
    );
}

#[test]
fn ascii_polydata() {
    let (m, d) = parse(ASCII.as_bytes()).unwrap();
    assert_eq!(m.positions.len(), 4);
    // The polygon (cell 0) comes before the strip (cell 1).
    assert_eq!(
        m.triangles,
        vec![[0, 1, 3], [0, 3, 2], [0, 1, 2], [2, 1, 3]]
    );
    assert_eq!(d.triangle_cells, vec![0, 0, 1, 1]);
    assert_eq!(d.values(0).unwrap().data, vec![0.0, 1.5, 3.0, 4.5]);
    assert_eq!(d.arrays[1].color, Some(Encoding::Srgb));
    assert_eq!(
        d.values(1).unwrap().data,
        vec![1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    );
}

#[test]
fn errors_name_piece_array_and_line() {
    let edit = |from: &str, to: &str| ASCII.replacen(from, to, 1).into_bytes();
    assert_err(b"<a/>", "line 1", "not a VTK XML file");
    assert_err(
        b"<VTKFile type=\"PolyData\"><PolyData>",
        "line 1",
        "ends inside",
    );
    assert_err(
        &edit("type=\"PolyData\"", "type=\"ImageData\""),
        "line 2",
        "dcrt reads PolyData",
    );
    assert_err(
        &edit("0 1.5 3 4.5", "0 1.5 3"),
        "Piece 0: point array 'p' (line 6)",
        "3 values where 4 tuples of 1 need 4",
    );
    assert_err(
        &edit("0 1.5 3 4.5", "0 1.5 3 4.5 6"),
        "point array 'p'",
        "5 values",
    );
    assert_err(
        &edit("0 1.5 3 4.5", "0 1.5 x 4.5"),
        "point array 'p'",
        "value 2: expected a float32 value, found 'x'",
    );
    assert_err(
        &edit("-0.5 0.5 0 0.5", "-0.5 nan 0 0.5"),
        "Piece 0: Points (line 19)",
        "point 2: coordinate is not finite",
    );
    assert_err(
        &edit("0 1 3 2", "0 1 3 4"),
        "Polys cell 0",
        "point index 4 out of range (4 points)",
    );
    assert_err(
        &edit("255 0 0 0 0 255", "256 0 0 0 0 255"),
        "cell array 'rgb'",
        "out of range for uint8",
    );
    assert_err(
        &edit("NumberOfPolys=\"1\"", "NumberOfPolys=\"2\""),
        "Polys offsets",
        "1 values where 2 tuples",
    );
    assert_err(
        &edit(
            "Name=\"offsets\" format=\"ascii\">4</",
            "Name=\"offsets\" format=\"ascii\">5</",
        ),
        "Strips connectivity",
        "4 values where 5 tuples",
    );
    assert_err(
        &edit("type=\"Float32\" Name=\"p\"", "type=\"String\" Name=\"p\""),
        "point array 'p'",
        "unsupported type 'String'",
    );
    assert_err(
        &edit("</Points>", "</Pints>"),
        "line 23",
        "not well-formed XML",
    );
}

/// Found by `dcrt bench fuzz`: an inline compression header whose base64 text is
/// padded early decodes to fewer bytes than the header's words (it panicked).
#[test]
fn short_inline_header_is_an_error() {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/vtk/poly-binary-zlib-64.vtp");
    let text = std::fs::read_to_string(file).unwrap();
    let head = "AgAAAAAAAAAoAAAAAAAAABAAAAAAAAAA";
    assert!(text.contains(head));
    assert_err(
        text.replacen(head, "AgAAAAAAAAAoAAAAAAAAABAAAAAAAAA=", 1)
            .as_bytes(),
        "point array 'temperature' (line 6)",
        "its header has 23 bytes, not 24",
    );
}

/// Found by `dcrt bench fuzz`: appended base64 data with a padding character in
/// the middle decoded to fewer bytes than the array needs (it panicked).
#[test]
fn short_appended_data_is_an_error() {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/vtk/poly-base64-raw-32.vtp");
    let mut b = std::fs::read(file).unwrap();
    assert_eq!(b[4121], b'A');
    b[4121] = b'=';
    assert_err(
        &b,
        "cell array 'region' (line 30)",
        "19 bytes of data, the array needs 20",
    );
}

#[test]
fn random_input_never_panics() {
    let mut seed = 0x0bad_cafe_1234_5678u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for _ in 0..2000 {
        let mut b = ASCII.as_bytes().to_vec();
        for _ in 0..1 + next() % 4 {
            let i = next() as usize % b.len();
            b[i] = match next() % 3 {
                0 => next() as u8,
                1 => b"0123456789 <>/\"=-."[next() as usize % 18],
                _ => b[i].wrapping_add(1),
            };
        }
        if next() % 3 == 0 {
            b.truncate(next() as usize % (b.len() + 1));
        }
        if let Ok((m, _)) = parse(&b) {
            m.validate(Path::new("fuzz.vtp")).unwrap();
        }
    }
}
