//! ParaView camera files (`.pvcc`, written by ParaView's "Save Camera" of the Adjust Camera
//! dialog): an XML `PVCameraConfiguration` holding a `RenderView` proxy whose properties
//! `CameraPosition`, `CameraFocalPoint`, `CameraViewUp` (3 elements each), `CameraViewAngle`,
//! and, when `CameraParallelProjection` is 1, `CameraParallelScale` make dcrt's camera. Other
//! properties (centre of rotation, eye angle, focal disk) are read over. Errors name the file and
//! the property.

use super::Camera;
use crate::error::{Error, Result};
use std::path::Path;

/// Reads the camera saved in the ParaView camera file at `path`.
pub fn load_pvcc(path: &Path) -> Result<Camera> {
    super::check_regular(path, "camera file")?;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_pvcc(&bytes, path)
}

/// Parses a ParaView camera file's bytes; `origin` names it in errors.
pub fn parse_pvcc(bytes: &[u8], origin: &Path) -> Result<Camera> {
    use quick_xml::events::Event;
    let bad = |at: Option<String>, m: String| Error::format(origin, at, m);
    let mut reader = quick_xml::Reader::from_reader(bytes);
    let mut buf = Vec::new();
    // (property name, elements by index)
    let mut props: Vec<(String, Vec<(usize, String)>)> = Vec::new();
    let mut root = None;
    let line = |pos: u64| {
        1 + bytes[..(pos as usize).min(bytes.len())]
            .iter()
            .filter(|&&c| c == b'\n')
            .count()
    };
    loop {
        let pos = reader.buffer_position();
        let event = reader.read_event_into(&mut buf).map_err(|e| {
            bad(
                Some(format!("line {}", line(reader.error_position()))),
                format!("not well-formed XML: {e}"),
            )
        })?;
        let (e, _empty) = match &event {
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::Eof => break,
            _ => {
                buf.clear();
                continue;
            }
        };
        let name = e.name().as_ref().to_string();
        let attr = |key: &str| -> Result<Option<String>> {
            for a in e.attributes() {
                let a = a.map_err(|err| {
                    bad(
                        Some(format!("line {}", line(pos))),
                        format!("bad attribute: {err}"),
                    )
                })?;
                if a.key.as_ref() == key {
                    return Ok(Some(a.value.trim().to_string()));
                }
            }
            Ok(None)
        };
        if root.is_none() {
            root = Some(name.clone());
        }
        match name.as_str() {
            "Property" => {
                let n = attr("name")?.unwrap_or_default();
                props.push((n, Vec::new()));
            }
            "Element" => {
                if let Some((_, elements)) = props.last_mut() {
                    let index = attr("index")?.and_then(|i| i.parse().ok()).ok_or_else(|| {
                        bad(
                            Some(format!("line {}", line(pos))),
                            "an Element without an index".into(),
                        )
                    })?;
                    elements.push((index, attr("value")?.unwrap_or_default()));
                }
            }
            _ => {}
        }
        buf.clear();
    }
    if root.as_deref() != Some("PVCameraConfiguration") {
        return Err(bad(
            Some("line 1".into()),
            format!(
                "not a ParaView camera file: the document's element is {}, not \
                 PVCameraConfiguration",
                root.map_or("missing".into(), |r| format!("<{r}>"))
            ),
        ));
    }
    let values = |name: &str, n: usize| -> Result<Option<Vec<f64>>> {
        let Some((_, elements)) = props.iter().find(|(p, _)| p == name) else {
            return Ok(None);
        };
        let at = || Some(format!("property {name}"));
        let mut v = vec![None; n];
        for (i, text) in elements {
            let slot = v.get_mut(*i).ok_or_else(|| {
                bad(
                    at(),
                    format!("element index {i}: the property has {n} elements"),
                )
            })?;
            let x: f64 = text
                .parse()
                .map_err(|_| bad(at(), format!("element {i}: '{text}' is not a number")))?;
            *slot = Some(x);
        }
        v.into_iter()
            .enumerate()
            .map(|(i, x)| x.ok_or_else(|| bad(at(), format!("element {i} is missing"))))
            .collect::<Result<Vec<f64>>>()
            .map(Some)
    };
    let need = |name: &str, n: usize| -> Result<Vec<f64>> {
        values(name, n)?.ok_or_else(|| bad(None, format!("no {name} property")))
    };
    let three = |name: &str| -> Result<[f64; 3]> {
        let v = need(name, 3)?;
        Ok([v[0], v[1], v[2]])
    };
    let parallel = values("CameraParallelProjection", 1)?.is_some_and(|v| v[0] != 0.0);
    let camera = Camera {
        position: three("CameraPosition")?,
        focal_point: three("CameraFocalPoint")?,
        view_up: three("CameraViewUp")?,
        view_angle: need("CameraViewAngle", 1)?[0],
        parallel_scale: match parallel {
            true => Some(need("CameraParallelScale", 1)?[0]),
            false => None,
        },
    };
    camera.validate().map_err(|e| bad(None, e.to_string()))?;
    Ok(camera)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A camera file as ParaView 5.x saves it.
    pub const PVCC: &str = r#"<?xml version="1.0"?>
<PVCameraConfiguration description="ParaView camera configuration" version="1.0">
  <Proxy group="views" type="RenderView" id="4785" servers="21">
    <Property name="CameraPosition" id="4785.CameraPosition" number_of_elements="3">
      <Element index="0" value="0.5"/>
      <Element index="1" value="-2.25"/>
      <Element index="2" value="3"/>
    </Property>
    <Property name="CameraFocalPoint" id="4785.CameraFocalPoint" number_of_elements="3">
      <Element index="0" value="0"/>
      <Element index="1" value="0"/>
      <Element index="2" value="0.125"/>
    </Property>
    <Property name="CameraViewUp" id="4785.CameraViewUp" number_of_elements="3">
      <Element index="0" value="0"/>
      <Element index="1" value="0"/>
      <Element index="2" value="1"/>
    </Property>
    <Property name="CenterOfRotation" id="4785.CenterOfRotation" number_of_elements="3">
      <Element index="0" value="0"/>
      <Element index="1" value="0"/>
      <Element index="2" value="0"/>
    </Property>
    <Property name="RotationFactor" id="4785.RotationFactor" number_of_elements="1">
      <Element index="0" value="1"/>
    </Property>
    <Property name="CameraViewAngle" id="4785.CameraViewAngle" number_of_elements="1">
      <Element index="0" value="30"/>
    </Property>
    <Property name="CameraFocalDisk" id="4785.CameraFocalDisk" number_of_elements="1">
      <Element index="0" value="1"/>
    </Property>
    <Property name="CameraFocalDistance" id="4785.CameraFocalDistance" number_of_elements="1">
      <Element index="0" value="0"/>
    </Property>
    <Property name="CameraParallelScale" id="4785.CameraParallelScale" number_of_elements="1">
      <Element index="0" value="1.75"/>
    </Property>
    <Property name="CameraParallelProjection" id="4785.CameraParallelProjection" number_of_elements="1">
      <Element index="0" value="0"/>
      <Domain name="bool" id="4785.CameraParallelProjection.bool"/>
    </Property>
  </Proxy>
</PVCameraConfiguration>
"#;

    fn parse(text: &str) -> Result<Camera> {
        parse_pvcc(text.as_bytes(), Path::new("v.pvcc"))
    }

    #[test]
    fn reads_paraviews_camera() {
        let c = parse(PVCC).unwrap();
        assert_eq!(c.position, [0.5, -2.25, 3.0]);
        assert_eq!(c.focal_point, [0.0, 0.0, 0.125]);
        assert_eq!(c.view_up, [0.0, 0.0, 1.0]);
        assert_eq!(c.view_angle, 30.0);
        assert_eq!(c.parallel_scale, None);
        let p = PVCC.replace(
            "<Element index=\"0\" value=\"0\"/>\n      <Domain",
            "<Element index=\"0\" value=\"1\"/>\n      <Domain",
        );
        assert_eq!(parse(&p).unwrap().parallel_scale, Some(1.75));
    }

    #[test]
    fn errors_name_file_and_property() {
        let err = |text: &str| parse(text).unwrap_err().to_string();
        let e = err(&PVCC.replace("value=\"-2.25\"", "value=\"far\""));
        assert!(
            e.contains("v.pvcc") && e.contains("property CameraPosition") && e.contains("'far'"),
            "{e}"
        );
        let e = err(&PVCC.replace("CameraFocalPoint", "CameraFocus"));
        assert!(e.contains("no CameraFocalPoint property"), "{e}");
        let e = err(&PVCC.replace("<Element index=\"2\" value=\"1\"/>", ""));
        assert!(
            e.contains("property CameraViewUp") && e.contains("element 2 is missing"),
            "{e}"
        );
        let e = err(&PVCC.replace(
            "<Element index=\"0\" value=\"30\"/>",
            "<Element index=\"0\" value=\"180\"/>",
        ));
        assert!(
            e.contains("v.pvcc") && e.contains("view_angle must be between 0 and 180"),
            "{e}"
        );
        let e = err("<Camera/>");
        assert!(e.contains("not a ParaView camera file"), "{e}");
        let e = err(&PVCC[..300]);
        assert!(e.contains("v.pvcc"), "{e}");
    }
}
