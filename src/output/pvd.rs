//! ParaView collection (`.pvd`) time series.

use std::io;
use std::path::{Component, Path, PathBuf};

use super::atomic::write_atomic;

/// A ParaView collection (`.pvd`) listing one data file per time step.
///
/// The `.pvd` file is rewritten atomically on every [`push`](PvdSeries::push), so after each
/// step the series on disk is complete, valid XML, and lists only files that exist (push a file
/// after writing it). File names are stored relative to the `.pvd`'s folder, with `/`
/// separators. Creating the series touches no file; the first push writes it (replacing any
/// older file of that name).
///
/// ```text
/// <?xml version="1.0"?>
/// <VTKFile type="Collection" version="0.1" byte_order="LittleEndian">
///   <Collection>
///     <DataSet timestep="0" group="" part="0" file="particles_0000.vtu"/>
///     <DataSet timestep="0.5" group="" part="0" file="particles_0001.vtu"/>
///   </Collection>
/// </VTKFile>
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct PvdSeries {
    path: PathBuf,
    entries: Vec<(f64, String)>,
}

impl PvdSeries {
    /// A new, empty series to be written to `path` (e.g. `OUT_DIR/particles.pvd`).
    pub fn new(path: impl Into<PathBuf>) -> Self {
        PvdSeries {
            path: path.into(),
            entries: Vec::new(),
        }
    }

    /// Where the series is written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The `(time, file name relative to the .pvd's folder)` entries, in push order.
    pub fn entries(&self) -> &[(f64, String)] {
        &self.entries
    }

    /// Appends the data file `file_name` at `time` and rewrites the `.pvd` atomically.
    ///
    /// `file_name` is relative to the `.pvd`'s folder (e.g. `particles_0003.vtu`), or an absolute
    /// path inside that folder. Errors (and the series is left unchanged, in memory and on disk)
    /// if `time` is not finite (`InvalidInput`), the name is empty or an absolute path outside
    /// the folder (`InvalidInput`), the file does not exist (`NotFound`), or the write fails.
    pub fn push(&mut self, time: f64, file_name: &str) -> io::Result<()> {
        if !time.is_finite() {
            return Err(invalid(format!(
                "{}: time {time} of {file_name:?} is not finite",
                self.path.display()
            )));
        }
        let relative = self.relative_name(file_name)?;
        let target = self.folder().join(&relative);
        if !target.is_file() {
            return Err(io::Error::new(
                io::ErrorKind::NotFound,
                format!(
                    "{}: refusing to list {} which does not exist (write it before pushing)",
                    self.path.display(),
                    target.display()
                ),
            ));
        }
        self.entries.push((time, relative));
        let result = write_atomic(&self.path, self.to_xml().as_bytes());
        if result.is_err() {
            self.entries.pop();
        }
        result
    }

    /// Replaces the entries with `entries` (those of a checkpoint, when a run is resumed) and
    /// rewrites the `.pvd` atomically, or removes it when there are none. Every listed file
    /// must exist (`NotFound` otherwise, and the series is left unchanged).
    pub fn restore_entries(&mut self, entries: Vec<(f64, String)>) -> io::Result<()> {
        if let Some((_, missing)) = entries
            .iter()
            .find(|(_, name)| !self.folder().join(name).is_file())
        {
            return Err(io::Error::new(
                io::ErrorKind::NotFound,
                format!("{}: {missing} is missing", self.path.display()),
            ));
        }
        self.entries = entries;
        if self.entries.is_empty() {
            return match std::fs::remove_file(&self.path) {
                Err(e) if e.kind() != io::ErrorKind::NotFound => Err(e),
                _ => Ok(()),
            };
        }
        write_atomic(&self.path, self.to_xml().as_bytes())
    }

    /// The `.pvd` document for the current entries.
    fn to_xml(&self) -> String {
        let mut xml = String::from(
            "<?xml version=\"1.0\"?>\n\
             <VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  \
             <Collection>\n",
        );
        for (time, file) in &self.entries {
            xml.push_str(&format!(
                "    <DataSet timestep=\"{}\" group=\"\" part=\"0\" file=\"{}\"/>\n",
                format_time(*time),
                escape_attribute(file)
            ));
        }
        xml.push_str("  </Collection>\n</VTKFile>\n");
        xml
    }

    fn folder(&self) -> &Path {
        match self.path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        }
    }

    /// `file_name` relative to the `.pvd`'s folder, with `/` separators.
    fn relative_name(&self, file_name: &str) -> io::Result<String> {
        let name = Path::new(file_name);
        if file_name.is_empty() {
            return Err(invalid(format!("{}: empty file name", self.path.display())));
        }
        let relative = if name.is_absolute() {
            let folder = self.folder();
            let folder_abs = std::path::absolute(folder).unwrap_or_else(|_| folder.to_path_buf());
            name.strip_prefix(&folder_abs).map_err(|_| {
                invalid(format!(
                    "{}: {file_name} is not inside the series' folder {}",
                    self.path.display(),
                    folder_abs.display()
                ))
            })?
        } else {
            name
        };
        let parts: Vec<String> = relative
            .components()
            .filter(|c| !matches!(c, Component::CurDir))
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        if parts.is_empty() {
            return Err(invalid(format!(
                "{}: {file_name:?} does not name a file",
                self.path.display()
            )));
        }
        Ok(parts.join("/"))
    }
}

/// Shortest round-trip decimal form, switching to exponent form for very small or large times.
fn format_time(t: f64) -> String {
    let a = t.abs();
    if a == 0.0 || (1e-4..1e15).contains(&a) {
        format!("{t}")
    } else {
        format!("{t:e}")
    }
}

/// `s` with the five XML special characters escaped, for an attribute value.
pub(super) fn escape_attribute(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

fn invalid(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

#[cfg(test)]
mod tests {
    use super::super::atomic::test_dir::TestDir;
    use super::super::{Field, read_vtu, step_file_name, vertex_cells, write_vtu};
    use super::*;

    /// An element's name and its `(attribute, raw value)` pairs.
    type Element = (String, Vec<(String, String)>);

    /// A minimal XML well-formedness check for the documents written here: a prolog, then
    /// properly nested elements whose attributes are `name="value"` without raw `<` or `&`
    /// (other than entities), and nothing but whitespace between tags. Returns every element
    /// as `(name, attributes)` in document order.
    fn parse_xml(doc: &str) -> Result<Vec<Element>, String> {
        let rest = doc
            .strip_prefix("<?xml version=\"1.0\"?>")
            .ok_or("missing XML prolog")?;
        let mut stack: Vec<String> = Vec::new();
        let mut elements = Vec::new();
        let mut rest = rest;
        loop {
            let trimmed = rest.trim_start();
            if trimmed.is_empty() {
                break;
            }
            let inner_end = trimmed.find('>').ok_or("unterminated tag")?;
            let tag = trimmed.strip_prefix('<').ok_or("text outside tags")?;
            let tag = &tag[..inner_end - 1];
            rest = &trimmed[inner_end + 1..];
            if let Some(name) = tag.strip_prefix('/') {
                if stack.pop().as_deref() != Some(name) {
                    return Err(format!("unbalanced </{name}>"));
                }
                continue;
            }
            let (tag, self_closing) = match tag.strip_suffix('/') {
                Some(t) => (t, true),
                None => (tag, false),
            };
            let mut words = tag.splitn(2, char::is_whitespace);
            let name = words.next().ok_or("empty tag")?.to_string();
            let mut attrs = Vec::new();
            let mut a = words.next().unwrap_or("").trim();
            while !a.is_empty() {
                let eq = a.find("=\"").ok_or(format!("bad attribute in <{name}>"))?;
                let key = a[..eq].trim().to_string();
                let after = &a[eq + 2..];
                let close = after.find('"').ok_or("unterminated attribute")?;
                let value = &after[..close];
                if value.contains('<') {
                    return Err(format!("raw < in attribute {key}"));
                }
                for (i, _) in value.match_indices('&') {
                    let entity = &value[i..];
                    if !["&amp;", "&lt;", "&gt;", "&quot;", "&apos;"]
                        .iter()
                        .any(|e| entity.starts_with(e))
                    {
                        return Err(format!("raw & in attribute {key}"));
                    }
                }
                attrs.push((key, value.to_string()));
                a = after[close + 1..].trim_start();
            }
            if stack.is_empty() && !elements.is_empty() {
                return Err("more than one root element".into());
            }
            elements.push((name.clone(), attrs));
            if !self_closing {
                stack.push(name);
            }
        }
        if stack.is_empty() {
            Ok(elements)
        } else {
            Err(format!("unclosed elements {stack:?}"))
        }
    }

    /// `(timestep, file)` of the `DataSet` elements of a `.pvd` file.
    fn listed(path: &Path) -> Vec<(String, String)> {
        let doc = std::fs::read_to_string(path).unwrap();
        let elements = parse_xml(&doc).unwrap_or_else(|e| panic!("invalid XML ({e}):\n{doc}"));
        assert_eq!(elements[0].0, "VTKFile");
        assert!(
            elements[0]
                .1
                .contains(&("type".into(), "Collection".into()))
        );
        assert_eq!(elements[1].0, "Collection");
        elements[2..]
            .iter()
            .map(|(name, attrs)| {
                assert_eq!(name, "DataSet");
                let get = |k: &str| attrs.iter().find(|a| a.0 == k).unwrap().1.clone();
                (get("timestep"), get("file"))
            })
            .collect()
    }

    fn write_step(folder: &Path, name: &str) {
        let points = [[0.0, 0.0, 0.0], [1.0, 0.5, 0.0]];
        let stress = [1.0; 18];
        write_vtu(
            &folder.join(name),
            &points,
            &vertex_cells(2),
            &[Field::new("cauchy_stress", 9, &stress)],
            &[],
        )
        .unwrap();
    }

    #[test]
    fn series_is_valid_xml_listing_entries_in_order_after_every_push() {
        let dir = TestDir::new("pvd");
        let pvd = dir.path().join("particles.pvd");
        let mut series = PvdSeries::new(&pvd);
        assert!(!pvd.exists(), "new() must not touch the disk");
        let times = [0.0, 0.25, 0.5, 1.0e-7, 3.0e20];
        for (step, &t) in times.iter().enumerate() {
            let name = step_file_name("particles", step);
            write_step(dir.path(), &name);
            series.push(t, &name).unwrap();
            let on_disk = listed(&pvd);
            assert_eq!(on_disk.len(), step + 1);
            for (i, (time, file)) in on_disk.iter().enumerate() {
                assert_eq!(time.parse::<f64>().unwrap(), times[i]);
                assert_eq!(file, &step_file_name("particles", i));
                assert!(dir.path().join(file).is_file());
            }
        }
        assert_eq!(series.entries().len(), times.len());
        assert_eq!(
            series.entries()[1],
            (0.25, "particles_0001.vtu".to_string())
        );
        let doc = std::fs::read_to_string(&pvd).unwrap();
        assert!(doc.contains("timestep=\"0.25\""), "{doc}");
        assert!(doc.contains("timestep=\"1e-7\""), "{doc}");
        // No temporary files left: 5 .vtu files and the .pvd.
        assert_eq!(dir.file_names().len(), times.len() + 1);
        assert!(read_vtu(&dir.path().join("particles_0004.vtu")).is_ok());
    }

    #[test]
    fn refuses_missing_files_and_bad_times_leaving_the_series_unchanged() {
        let dir = TestDir::new("pvd-refuse");
        let pvd = dir.path().join("grid.pvd");
        let mut series = PvdSeries::new(&pvd);
        write_step(dir.path(), "grid_0000.vtu");
        series.push(0.0, "grid_0000.vtu").unwrap();
        let before = std::fs::read(&pvd).unwrap();

        let err = series.push(1.0, "grid_0001.vtu").unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::NotFound);
        assert!(err.to_string().contains("grid_0001.vtu"), "{err}");
        write_step(dir.path(), "grid_0001.vtu");
        for bad in [f64::NAN, f64::INFINITY] {
            let err = series.push(bad, "grid_0001.vtu").unwrap_err();
            assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
        }
        assert_eq!(
            series.push(1.0, "").unwrap_err().kind(),
            io::ErrorKind::InvalidInput
        );
        assert_eq!(
            series.push(1.0, "/elsewhere/x.vtu").unwrap_err().kind(),
            io::ErrorKind::InvalidInput
        );
        assert_eq!(series.entries().len(), 1);
        assert_eq!(std::fs::read(&pvd).unwrap(), before);
    }

    #[test]
    fn stores_names_relative_to_the_pvd_folder() {
        let dir = TestDir::new("pvd-relative");
        std::fs::create_dir(dir.path().join("vtu")).unwrap();
        write_step(&dir.path().join("vtu"), "a&b.vtu");
        write_step(dir.path(), "c.vtu");
        let mut series = PvdSeries::new(dir.path().join("s.pvd"));
        series.push(0.0, "./vtu/a&b.vtu").unwrap();
        let absolute = dir.path().join("c.vtu");
        series.push(1.0, absolute.to_str().unwrap()).unwrap();
        assert_eq!(series.entries()[0].1, "vtu/a&b.vtu");
        assert_eq!(series.entries()[1].1, "c.vtu");
        let on_disk = listed(&dir.path().join("s.pvd"));
        assert_eq!(on_disk[0].1, "vtu/a&amp;b.vtu");
    }

    #[test]
    fn formats_times_readably_and_exactly() {
        for t in [0.0, 1.0, 0.1, 2.5e-3, 123456.789, 1e-12, -3e30, 1e15] {
            assert_eq!(format_time(t).parse::<f64>().unwrap(), t);
        }
        assert_eq!(format_time(0.1), "0.1");
        assert_eq!(format_time(1e-12), "1e-12");
    }

    #[test]
    fn xml_checker_rejects_broken_documents() {
        assert!(parse_xml("<?xml version=\"1.0\"?>\n<a><b/></a>\n").is_ok());
        assert!(parse_xml("<?xml version=\"1.0\"?>\n<a><b></a>").is_err());
        assert!(parse_xml("<?xml version=\"1.0\"?>\n<a x=\"&\"/>").is_err());
        assert!(parse_xml("<a/>").is_err());
    }
}
