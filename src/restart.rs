//! Checkpoint files and resuming a run (`impm run SCENE --resume OUT_DIR`).
//!
//! A run that keeps checkpoints writes `OUT_DIR/checkpoint.json`, a small header, and the bulk
//! of the state in a binary file beside it, `OUT_DIR/checkpoint_NNNN.bin` (NNNN: the steps
//! done), after the initial state and after every output step (or every N steps, `impm run
//! --checkpoint-every N`). The header holds everything the rest of the run depends on:
//!
//! ```text
//! format, version          "impm checkpoint", FORMAT_VERSION, and the impm version that wrote it
//! scene, scene_hash, set   the scene file, a hash of its bytes, the --set overrides (RunIdentity)
//! steps_done               the load step the state is after (the schedule position)
//! parts                    every owner's saved state (checkpoint::CheckpointPart): its name and
//!                          how many numbers it has in the binary file, in order (the points'
//!                          x, u, F, V; each module's own: plastic history, traction points...)
//! data                     the binary file's name, its length in bytes and its FNV-1a hash
//! series                   the entries of every .pvd series (checkpoint::CheckpointSeries)
//! steps, warnings          the records: summary.json's steps (history.csv is made from them)
//! pieces                   with decomposed points over several processes (else null): the
//!                          parts the pieces carry, the dimension, the slab axis and the points
//!                          per cell layer along it, and each piece's file, points, bytes,
//!                          FNV-1a hash and first and last cell layer
//! ```
//!
//! Numbers are stored exactly, so a resumed run continues from the very same state and writes
//! bit-identical files: in the binary file every `f64` as the 8 little-endian bytes of its
//! bits, the parts one after the other; in the header (the series' times) as the 16
//! hexadecimal digits of its bits. Both files are written atomically and durably (a temporary
//! file, fsynced, renamed over the file, the folder fsynced), the binary one first: a run
//! killed between the two leaves the previous header with its own binary file, which is
//! removed only after the new header is in place.
//! Reading checks the binary file's length and hash against the header, so a truncated or
//! damaged file is refused with a message instead of resuming from a wrong state. At 100 000
//! points the pair is half the size of format 1's hexadecimal JSON (docs/restart.md). The step
//! control needs no state of its own: `StepCutting` starts every load step afresh, so the
//! position in the schedule is `steps_done`.
//!
//! Resuming refuses a checkpoint of another format version or impm version (the results would
//! not be those of the interrupted run) and one whose scene file or `--set` overrides differ
//! from the command's, saying which. The hash is 64-bit FNV-1a over the scene file's bytes,
//! written here in a few lines: it detects a changed file, it is no security measure, and it
//! must be stable across Rust releases (std's `DefaultHasher` is not promised to be). Files a
//! scene imports are not hashed.
//!
//! Under `mpirun` there is one header, process 0's, in this format. Without decomposed points,
//! or with them on one process, it is the serial checkpoint (process 0 holds every point).
//! With decomposed points over several processes it is **in pieces** ([`Pieces`]): each
//! process writes its own points' records to `checkpoint_NNNN_pK.bin` in process 0's folder
//! (durably: a temporary file, fsynced, renamed; [`write_piece`]), the binary file holds only
//! the parts the records do not carry, and the header, written last, names every piece with
//! its points, length, hash and cell layers (`effects::distributed::checkpoint`). A crash
//! before the header leaves the previous checkpoint, whose files are removed only once the new
//! header is in place. Reading checks that every piece exists with its length; a piece's hash
//! is checked by the process that reads it ([`read_piece`]). A checkpoint in pieces is resumed
//! with decomposed points over any number of processes; a serial or replicated `--resume`
//! refuses it, saying how ([`Checkpoint::needs_decomposition`]). Every process of a resumed
//! run reads the header from process 0's folder (the others run into scratch folders of their
//! own). All the files of a checkpoint are written durably (fsynced before the rename, the
//! folder after it), serial ones too.

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use crate::output::is_checkpoint_data;

/// The checkpoint's file name in the output folder.
pub const CHECKPOINT_FILE: &str = "checkpoint.json";

/// The version of the checkpoint format; a resumed run refuses any other.
pub const FORMAT_VERSION: u64 = 2;

/// The binary file of the checkpoint after `steps_done` steps (see the module docs).
pub fn data_file_name(steps_done: usize) -> String {
    format!("checkpoint_{steps_done:04}.bin")
}

const FORMAT_NAME: &str = "impm checkpoint";

/// What a run was made of: the scene file (its path as given, and a hash of its bytes) and the
/// `--set` overrides. A run resumes only a checkpoint of the same identity.
#[derive(Clone, Debug, PartialEq)]
pub struct RunIdentity {
    pub scene: String,
    pub scene_hash: String,
    pub overrides: Vec<(String, String)>,
}

impl RunIdentity {
    /// The identity of a run of the scene file `scene` with `overrides`.
    pub fn of(scene: &Path, overrides: &[(String, String)]) -> Result<Self, String> {
        let bytes = std::fs::read(scene)
            .map_err(|e| format!("cannot read the scene {}: {e}", scene.display()))?;
        Ok(Self {
            scene: scene.display().to_string(),
            scene_hash: format!("{:016x}", fnv1a(&bytes)),
            overrides: overrides.to_vec(),
        })
    }

    /// Why a checkpoint of `saved` cannot be resumed by this run, if it cannot.
    fn differs_from(&self, saved: &RunIdentity, file: &Path) -> Option<String> {
        if self.scene_hash != saved.scene_hash {
            return Some(format!(
                "{} was written by a run of the scene {} as it was then (hash {}), but {} now \
                 hashes to {}: the scene changed, so the run cannot be continued; run it anew \
                 without --resume",
                file.display(),
                saved.scene,
                saved.scene_hash,
                self.scene,
                self.scene_hash
            ));
        }
        if self.overrides != saved.overrides {
            return Some(format!(
                "{} was written by a run with {}, but this command has {}: give the same --set \
                 values to continue that run, or run anew without --resume",
                file.display(),
                describe_overrides(&saved.overrides),
                describe_overrides(&self.overrides)
            ));
        }
        None
    }
}

fn describe_overrides(overrides: &[(String, String)]) -> String {
    if overrides.is_empty() {
        return "no --set".to_string();
    }
    overrides
        .iter()
        .map(|(name, value)| format!("--set {name}={value}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// 64-bit FNV-1a (see the module docs for why it is written here).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |hash, &byte| {
        (hash ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The contents of a checkpoint file (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    pub identity: RunIdentity,
    pub steps_done: usize,
    /// Every owner's part: `(name, numbers)`, in registration order.
    pub parts: Vec<(String, Vec<f64>)>,
    /// Every series: `(.pvd file name, (time, file) entries)`.
    pub series: Vec<(String, Vec<(f64, String)>)>,
    /// The completed steps' records, as in `summary.json`.
    pub steps: Vec<Value>,
    /// The run's warnings so far.
    pub warnings: Vec<String>,
    /// With decomposed points over several processes, the pieces holding the points (their
    /// parts are then not in the binary file); `None` in the serial format.
    pub pieces: Option<Pieces>,
}

/// The pieces of a checkpoint written by a decomposed run over several processes: each
/// process's points as records (`distributed::migration::PointRecord`, in `PointId` order) in
/// a file of its own, `checkpoint_NNNN_pK.bin` (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Pieces {
    /// The parts the points' records carry (each point's state), left out of the binary file.
    pub carried: Vec<String>,
    /// The dimension of the points' records.
    pub dim: usize,
    /// The slab axis, and the points in each cell layer along it (over every piece): what a
    /// resumed run divides the points by, over any number of processes.
    pub axis: usize,
    pub layers: Vec<u64>,
    /// The pieces, by rank.
    pub files: Vec<Piece>,
    /// The folder holding the pieces (the checkpoint's; not written to the header).
    pub folder: PathBuf,
}

/// One process's piece of a checkpoint ([`Pieces`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    pub file: String,
    /// Its points, its length in bytes and its FNV-1a hash.
    pub points: u64,
    pub bytes: u64,
    pub fnv1a: u64,
    /// The first and last cell layer its points lie in (`None`: it has no points).
    pub layers: Option<(usize, usize)>,
}

/// The piece of process `rank` of the checkpoint after `steps_done` steps.
pub fn piece_file_name(steps_done: usize, rank: usize) -> String {
    format!("checkpoint_{steps_done:04}_p{rank}.bin")
}

/// Writes a piece's bytes (its numbers' little-endian bits) to `dir/name` durably (a
/// temporary file, fsynced, renamed over `name`, the folder fsynced); returns its length and
/// hash.
pub fn write_piece(dir: &Path, name: &str, data: &[u8]) -> Result<(u64, u64), String> {
    let path = dir.join(name);
    write_durable(&path, data).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok((data.len() as u64, fnv1a(data)))
}

/// The numbers of `piece` (of the checkpoint in `pieces.folder`), checked against the length
/// and hash the header gives; an error names the file.
pub fn read_piece(pieces: &Pieces, piece: &Piece) -> Result<Vec<f64>, String> {
    let path = pieces.folder.join(&piece.file);
    let header = Checkpoint::path_in(&pieces.folder);
    let contents = std::fs::read(&path).map_err(|e| missing_piece(&path, &header, &e))?;
    if contents.len() as u64 != piece.bytes {
        return Err(truncated(
            &path,
            contents.len() as u64,
            piece.bytes,
            &header,
        ));
    }
    if fnv1a(&contents) != piece.fnv1a {
        return Err(format!(
            "{} does not have the hash the checkpoint {} names: the piece is damaged, so the run \
             cannot be continued from it; run the scene anew without --resume",
            path.display(),
            header.display()
        ));
    }
    Ok(bytes_to_numbers(&contents).collect())
}

fn missing_piece(path: &Path, header: &Path, e: &std::io::Error) -> String {
    format!(
        "cannot read {}, a piece of the checkpoint {}: {e}; the run cannot be continued without \
         it: run the scene anew without --resume",
        path.display(),
        header.display()
    )
}

fn truncated(path: &Path, length: u64, named: u64, header: &Path) -> String {
    format!(
        "{} is {length} bytes long, but the checkpoint {} names {named}: the file is truncated or \
         damaged, so the run cannot be continued from it; run the scene anew without --resume",
        path.display(),
        header.display()
    )
}

fn bytes_to_numbers(data: &[u8]) -> impl Iterator<Item = f64> + '_ {
    data.chunks_exact(8).map(|bytes| {
        let mut word = [0u8; 8];
        word.copy_from_slice(bytes);
        f64::from_bits(u64::from_le_bytes(word))
    })
}

/// Replaces `path` by `contents` atomically and durably: a temporary file beside it
/// (`.NAME.PID.N.tmp`, which the output folder's cleaning knows), written and fsynced, renamed
/// over `path`, and the folder fsynced, so that after a crash `path` is the old file or the
/// whole new one, and a file the next header names is on the disk before the header.
fn write_durable(path: &Path, contents: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::other("the path names no file"))?
        .to_string_lossy()
        .into_owned();
    let (temp, mut file) = loop {
        let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let temp = folder.join(format!(".{name}.{}.{n}.tmp", std::process::id()));
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temp)
        {
            Ok(file) => break (temp, file),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    };
    let mut written = file.write_all(contents);
    if written.is_ok() {
        written = file.sync_all();
    }
    drop(file);
    if written.is_ok() {
        written = std::fs::rename(&temp, path);
    }
    if let Err(e) = written {
        let _ = std::fs::remove_file(&temp);
        return Err(e);
    }
    // the rename itself on the disk (best effort: not every file system lets a folder sync)
    if let Ok(dir) = std::fs::File::open(folder) {
        let _ = dir.sync_all();
    }
    Ok(())
}

impl Checkpoint {
    /// The checkpoint file of the output folder `dir`.
    pub fn path_in(dir: &Path) -> PathBuf {
        dir.join(CHECKPOINT_FILE)
    }

    /// Writes the checkpoint into `dir` atomically and durably: the binary file of the parts,
    /// then the header naming it (and the pieces, which their processes wrote before); then
    /// removes the binary files and pieces of earlier checkpoints.
    pub fn write(&self, dir: &Path) -> Result<(), String> {
        let data_name = data_file_name(self.steps_done);
        let data_path = dir.join(&data_name);
        let mut data =
            Vec::with_capacity(8 * self.parts.iter().map(|(_, v)| v.len()).sum::<usize>());
        for value in self.parts.iter().flat_map(|(_, values)| values) {
            data.extend_from_slice(&value.to_bits().to_le_bytes());
        }
        write_durable(&data_path, &data).map_err(|e| format!("{}: {e}", data_path.display()))?;
        let path = Self::path_in(dir);
        let header = self.to_json(&data_name, &data);
        let text = serde_json::to_string(&header).map_err(|e| e.to_string())?;
        write_durable(&path, text.as_bytes()).map_err(|e| format!("{}: {e}", path.display()))?;
        let mut keep = vec![data_name];
        if let Some(pieces) = &self.pieces {
            keep.extend(pieces.files.iter().map(|piece| piece.file.clone()));
        }
        remove_other_data_files(dir, &keep)
    }

    /// Why this checkpoint cannot be resumed by a run whose points are not decomposed over
    /// `mpirun`, if it cannot (it is in pieces); `dir` is its folder.
    pub fn needs_decomposition(&self, dir: &Path) -> Option<String> {
        let pieces = self.pieces.as_ref()?;
        Some(format!(
            "{} was written in {} pieces by a run with decomposed points (mpirun -n {} .. \
             --decompose: {} ..): it is resumed only with decomposed points, over any number of \
             processes: mpirun -n N impm run {} --decompose --resume {}",
            Self::path_in(dir).display(),
            pieces.files.len(),
            pieces.files.len(),
            pieces.files.first().map_or("", |piece| piece.file.as_str()),
            self.identity.scene,
            dir.display()
        ))
    }

    /// Reads the checkpoint of `dir` and checks that `identity` may resume it.
    pub fn read(dir: &Path, identity: &RunIdentity) -> Result<Self, String> {
        let path = Self::path_in(dir);
        let text = std::fs::read_to_string(&path).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => format!(
                "there is no checkpoint in {} ({CHECKPOINT_FILE}): the run did not get to write \
                 one, or the folder is not a run's output folder; run the scene anew without \
                 --resume",
                dir.display()
            ),
            _ => format!("cannot read {}: {e}", path.display()),
        })?;
        let value: Value = serde_json::from_str(&text)
            .map_err(|e| format!("{} is not a valid checkpoint: {e}", path.display()))?;
        let checkpoint = Self::from_json(&value, &path, dir)?;
        match identity.differs_from(&checkpoint.identity, &path) {
            Some(why) => Err(why),
            None => Ok(checkpoint),
        }
    }

    fn to_json(&self, data_name: &str, data: &[u8]) -> Value {
        json!({
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "impm": env!("CARGO_PKG_VERSION"),
            "scene": self.identity.scene,
            "scene_hash": self.identity.scene_hash,
            "set": self.identity.overrides,
            "steps_done": self.steps_done,
            "parts": self.parts.iter().map(|(name, values)| json!({
                "name": name,
                "count": values.len(),
            })).collect::<Vec<_>>(),
            "data": {
                "file": data_name,
                "bytes": data.len(),
                "fnv1a": format!("{:016x}", fnv1a(data)),
            },
            "series": self.series.iter().map(|(file, entries)| json!({
                "file": file,
                "entries": entries
                    .iter()
                    .map(|(time, name)| json!([hex(&[*time]), name]))
                    .collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "steps": self.steps,
            "warnings": self.warnings,
            "pieces": self.pieces.as_ref().map(|pieces| json!({
                "carried": pieces.carried,
                "dim": pieces.dim,
                "axis": pieces.axis,
                "layers": pieces.layers,
                "files": pieces.files.iter().map(|piece| json!({
                    "file": piece.file,
                    "points": piece.points,
                    "bytes": piece.bytes,
                    "fnv1a": format!("{:016x}", piece.fnv1a),
                    "layers": piece.layers.map(|(first, last)| [first, last]),
                })).collect::<Vec<_>>(),
            })),
        })
    }

    fn from_json(value: &Value, path: &Path, dir: &Path) -> Result<Self, String> {
        let bad = |what: &str| format!("{} is not a valid checkpoint: {what}", path.display());
        if value["format"].as_str() != Some(FORMAT_NAME) {
            return Err(bad("it is not an impm checkpoint file"));
        }
        let version = value["version"].as_u64();
        let impm = value["impm"].as_str().unwrap_or("?");
        if version != Some(FORMAT_VERSION) || impm != env!("CARGO_PKG_VERSION") {
            return Err(format!(
                "{} was written by impm {impm} (checkpoint format {}), this is impm {} (format \
                 {FORMAT_VERSION}): a checkpoint is resumed only by the version that wrote it; \
                 run the scene anew without --resume",
                path.display(),
                version.map_or("?".to_string(), |v| v.to_string()),
                env!("CARGO_PKG_VERSION")
            ));
        }
        let text = |v: &Value, what: &str| {
            v.as_str()
                .map(str::to_string)
                .ok_or_else(|| bad(&format!("{what} is not a string")))
        };
        let array = |v: &'_ Value, what: &str| -> Result<Vec<Value>, String> {
            v.as_array()
                .cloned()
                .ok_or_else(|| bad(&format!("{what} is not a list")))
        };
        let overrides = array(&value["set"], "set")?
            .iter()
            .map(|pair| {
                Ok((
                    text(&pair[0], "a --set name")?,
                    text(&pair[1], "a --set value")?,
                ))
            })
            .collect::<Result<_, String>>()?;
        let data = read_data(&value["data"], path, dir)?;
        let mut numbers = bytes_to_numbers(&data);
        let parts: Vec<(String, Vec<f64>)> = array(&value["parts"], "parts")?
            .iter()
            .map(|part| {
                let name = text(&part["name"], "a part's name")?;
                let count = part["count"]
                    .as_u64()
                    .ok_or_else(|| bad(&format!("the count of part {name} is not a count")))?;
                let values: Vec<f64> = numbers.by_ref().take(count as usize).collect();
                if values.len() as u64 != count {
                    return Err(bad(&format!(
                        "part {name} needs {count} numbers, the binary file holds fewer"
                    )));
                }
                Ok((name, values))
            })
            .collect::<Result<_, String>>()?;
        if numbers.next().is_some() {
            return Err(bad(
                "the binary file holds more numbers than the parts name",
            ));
        }
        let series = array(&value["series"], "series")?
            .iter()
            .map(|series| {
                let file = text(&series["file"], "a series' file")?;
                let entries = array(&series["entries"], "a series' entries")?
                    .iter()
                    .map(|entry| {
                        let time = unhex(&text(&entry[0], "an entry's time")?)
                            .and_then(|t| t.first().copied())
                            .ok_or_else(|| bad(&format!("a time of {file} is damaged")))?;
                        Ok((time, text(&entry[1], "an entry's file")?))
                    })
                    .collect::<Result<_, String>>()?;
                Ok((file, entries))
            })
            .collect::<Result<_, String>>()?;
        let warnings = array(&value["warnings"], "warnings")?
            .iter()
            .map(|w| text(w, "a warning"))
            .collect::<Result<_, String>>()?;
        Ok(Self {
            identity: RunIdentity {
                scene: text(&value["scene"], "scene")?,
                scene_hash: text(&value["scene_hash"], "scene_hash")?,
                overrides,
            },
            steps_done: value["steps_done"]
                .as_u64()
                .ok_or_else(|| bad("steps_done is not a count"))? as usize,
            parts,
            series,
            steps: array(&value["steps"], "steps")?,
            warnings,
            pieces: read_pieces(&value["pieces"], path, dir)?,
        })
    }
}

/// The pieces a checkpoint header names (`None` in the serial format), each checked to exist
/// with the length the header gives (its hash is checked by the process that reads it:
/// [`read_piece`]), so that every process of a resumed run refuses a missing or truncated
/// piece alike, naming it, before the run is built.
fn read_pieces(value: &Value, path: &Path, dir: &Path) -> Result<Option<Pieces>, String> {
    if value.is_null() {
        return Ok(None);
    }
    let bad = |what: &str| format!("{} is not a valid checkpoint: {what}", path.display());
    let count = |v: &Value, what: &str| {
        v.as_u64()
            .ok_or_else(|| bad(&format!("{what} is not a count")))
    };
    let list = |v: &Value, what: &str| {
        v.as_array()
            .cloned()
            .ok_or_else(|| bad(&format!("{what} is not a list")))
    };
    let carried = list(&value["carried"], "pieces.carried")?
        .iter()
        .map(|name| {
            name.as_str()
                .map(str::to_string)
                .ok_or_else(|| bad("a carried part's name is not a string"))
        })
        .collect::<Result<_, String>>()?;
    let layers = list(&value["layers"], "pieces.layers")?
        .iter()
        .map(|n| count(n, "a layer's points"))
        .collect::<Result<_, String>>()?;
    let mut files = Vec::new();
    for piece in list(&value["files"], "pieces.files")? {
        let file = piece["file"]
            .as_str()
            .filter(|name| {
                !name.contains(['/', '\\'])
                    && name.starts_with("checkpoint_")
                    && name.ends_with(".bin")
            })
            .ok_or_else(|| bad("a piece names no file"))?
            .to_string();
        let fnv1a = piece["fnv1a"]
            .as_str()
            .and_then(|hash| u64::from_str_radix(hash, 16).ok())
            .ok_or_else(|| bad(&format!("the hash of {file} is not a hash")))?;
        let layers = match &piece["layers"] {
            Value::Null => None,
            range => Some((
                count(&range[0], "a piece's first layer")? as usize,
                count(&range[1], "a piece's last layer")? as usize,
            )),
        };
        let bytes = count(&piece["bytes"], "a piece's bytes")?;
        let piece_path = dir.join(&file);
        let length = std::fs::metadata(&piece_path)
            .map_err(|e| missing_piece(&piece_path, path, &e))?
            .len();
        if length != bytes {
            return Err(truncated(&piece_path, length, bytes, path));
        }
        files.push(Piece {
            points: count(&piece["points"], "a piece's points")?,
            bytes,
            fnv1a,
            layers,
            file,
        });
    }
    Ok(Some(Pieces {
        carried,
        dim: count(&value["dim"], "pieces.dim")? as usize,
        axis: count(&value["axis"], "pieces.axis")? as usize,
        layers,
        files,
        folder: dir.to_path_buf(),
    }))
}

/// The binary file a checkpoint header names, checked against the length and hash it gives.
fn read_data(data: &Value, path: &Path, dir: &Path) -> Result<Vec<u8>, String> {
    let bad = |what: &str| format!("{} is not a valid checkpoint: {what}", path.display());
    let name = data["file"]
        .as_str()
        .filter(|name| !name.contains(['/', '\\']) && name.starts_with("checkpoint_"))
        .ok_or_else(|| bad("it names no binary file (data.file)"))?;
    let bytes = data["bytes"]
        .as_u64()
        .ok_or_else(|| bad("data.bytes is not a count"))?;
    let hash = data["fnv1a"]
        .as_str()
        .ok_or_else(|| bad("data.fnv1a is not a string"))?;
    let data_path = dir.join(name);
    let contents = std::fs::read(&data_path).map_err(|e| {
        format!(
            "cannot read {}, the state of the checkpoint {}: {e}; run the scene anew without --resume",
            data_path.display(),
            path.display()
        )
    })?;
    if contents.len() as u64 != bytes {
        return Err(format!(
            "{} is {} bytes long, but the checkpoint {} names {bytes}: the file is truncated or \
             damaged, so the run cannot be continued from it; run the scene anew without --resume",
            data_path.display(),
            contents.len(),
            path.display()
        ));
    }
    if format!("{:016x}", fnv1a(&contents)) != hash {
        return Err(format!(
            "{} does not have the hash the checkpoint {} names: the file is damaged, so the run \
             cannot be continued from it; run the scene anew without --resume",
            data_path.display(),
            path.display()
        ));
    }
    Ok(contents)
}

/// Removes the binary files and pieces of earlier checkpoints in `dir` (all but `keep`).
fn remove_other_data_files(dir: &Path, keep: &[String]) -> Result<(), String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        // only files: a folder of that name is not a checkpoint's (and not this run's)
        let is_file = entry.file_type().is_ok_and(|kind| kind.is_file());
        if is_file && !keep.iter().any(|kept| *kept == name) && is_checkpoint_data(&name) {
            std::fs::remove_file(entry.path())
                .map_err(|e| format!("{}: {e}", entry.path().display()))?;
        }
    }
    Ok(())
}

/// The numbers as the hexadecimal digits of their bits, 16 per number.
fn hex(values: &[f64]) -> String {
    values
        .iter()
        .map(|v| format!("{:016x}", v.to_bits()))
        .collect()
}

/// The numbers of [`hex`], or `None` if `text` is not such a string.
fn unhex(text: &str) -> Option<Vec<f64>> {
    if !text.len().is_multiple_of(16) || !text.is_ascii() {
        return None;
    }
    (0..text.len() / 16)
        .map(|i| {
            u64::from_str_radix(&text[16 * i..16 * (i + 1)], 16)
                .ok()
                .map(f64::from_bits)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_round_trip_bit_for_bit() {
        let values = [
            0.0,
            -0.0,
            1.0 / 3.0,
            f64::MIN_POSITIVE / 3.0,
            f64::NAN,
            -1e300,
        ];
        let back = unhex(&hex(&values)).unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&values));
        assert!(unhex("123").is_none());
        assert!(unhex("zzzzzzzzzzzzzzzz").is_none());
    }

    #[test]
    fn fnv1a_matches_its_reference_values() {
        // the published test vectors of 64-bit FNV-1a
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a(b"foobar"), 0x8594_4171_f739_67e8);
    }

    fn sample() -> Checkpoint {
        Checkpoint {
            identity: RunIdentity {
                scene: "scene.rhai".into(),
                scene_hash: "0123456789abcdef".into(),
                overrides: vec![("cells".into(), "4".into())],
            },
            steps_done: 3,
            parts: vec![("points".into(), vec![0.1, 0.2, -3.5])],
            series: vec![(
                "particles.pvd".into(),
                vec![(0.0, "particles_0000.vtu".into())],
            )],
            steps: vec![json!({"step": 1})],
            warnings: vec!["careful".into()],
            pieces: None,
        }
    }

    #[test]
    fn a_checkpoint_reads_back_and_refuses_another_identity() {
        let dir = std::env::temp_dir().join(format!("impm-restart-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let written = sample();
        written.write(&dir).unwrap();
        assert_eq!(Checkpoint::read(&dir, &written.identity).unwrap(), written);
        let mut other = written.identity.clone();
        other.overrides[0].1 = "8".into();
        let why = Checkpoint::read(&dir, &other).unwrap_err();
        assert!(
            why.contains("--set cells=4") && why.contains("--set cells=8"),
            "{why}"
        );
        other = written.identity.clone();
        other.scene_hash = "fedcba9876543210".into();
        let why = Checkpoint::read(&dir, &other).unwrap_err();
        assert!(why.contains("the scene changed"), "{why}");
        let mut text = std::fs::read_to_string(Checkpoint::path_in(&dir)).unwrap();
        text = text.replace("\"version\":2", "\"version\":99");
        std::fs::write(Checkpoint::path_in(&dir), text).unwrap();
        let why = Checkpoint::read(&dir, &written.identity).unwrap_err();
        assert!(why.contains("format 99"), "{why}");
        let _ = std::fs::remove_dir_all(&dir);
        let why = Checkpoint::read(&dir, &written.identity).unwrap_err();
        assert!(why.contains("there is no checkpoint"), "{why}");
    }

    /// The binary file is checked against the header: a truncated or damaged one is refused
    /// with its name; a run killed after writing the next binary file but before its header
    /// still resumes the previous checkpoint, and a complete write removes the earlier file.
    #[test]
    fn a_truncated_or_damaged_binary_file_is_refused_and_the_previous_one_kept() {
        let dir = std::env::temp_dir().join(format!("impm-restart-bin-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let written = sample();
        written.write(&dir).unwrap();
        let data = dir.join(data_file_name(3));
        let bytes = std::fs::read(&data).unwrap();
        assert_eq!(bytes.len(), 3 * 8);

        // killed between the binary file of step 4 and its header: step 3 is still read
        std::fs::write(dir.join(data_file_name(4)), [0u8; 16]).unwrap();
        assert_eq!(Checkpoint::read(&dir, &written.identity).unwrap(), written);
        let mut next = written.clone();
        next.steps_done = 4;
        next.write(&dir).unwrap();
        assert!(!data.exists(), "the earlier binary file is removed");
        assert_eq!(Checkpoint::read(&dir, &written.identity).unwrap(), next);
        let data = dir.join(data_file_name(4));

        std::fs::write(&data, &bytes[..20]).unwrap();
        let why = Checkpoint::read(&dir, &written.identity).unwrap_err();
        assert!(
            why.contains("checkpoint_0004.bin is 20 bytes long") && why.contains("truncated"),
            "{why}"
        );
        let mut damaged = bytes.clone();
        damaged[5] ^= 1;
        std::fs::write(&data, &damaged).unwrap();
        let why = Checkpoint::read(&dir, &written.identity).unwrap_err();
        assert!(why.contains("does not have the hash"), "{why}");
        std::fs::remove_file(&data).unwrap();
        let why = Checkpoint::read(&dir, &written.identity).unwrap_err();
        assert!(
            why.contains("cannot read") && why.contains("checkpoint_0004.bin"),
            "{why}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A checkpoint in pieces: the header names every piece and reads back as written; the
    /// earlier checkpoint's pieces go once the new header is in place, the new ones stay; a
    /// truncated or missing piece is refused when the header is read, a damaged one when the
    /// piece is, each naming the file; resuming it needs decomposed points, and says how.
    #[test]
    fn a_checkpoint_in_pieces_names_them_and_refuses_a_missing_or_damaged_one() {
        let dir = std::env::temp_dir().join(format!("impm-restart-pieces-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let numbers: [Vec<f64>; 2] = [vec![1.0, 2.0, 3.0], vec![-4.5, 1.0 / 3.0]];
        let files = numbers
            .iter()
            .enumerate()
            .map(|(k, values)| {
                let file = piece_file_name(3, k);
                let bytes: Vec<u8> = values
                    .iter()
                    .flat_map(|v| v.to_bits().to_le_bytes())
                    .collect();
                let (bytes, fnv1a) = write_piece(&dir, &file, &bytes).unwrap();
                Piece {
                    file,
                    points: k as u64 + 1,
                    bytes,
                    fnv1a,
                    layers: Some((k, k)),
                }
            })
            .collect();
        let mut written = sample();
        written.pieces = Some(Pieces {
            carried: vec!["points".into()],
            dim: 2,
            axis: 1,
            layers: vec![1, 2],
            files,
            folder: dir.clone(),
        });
        let earlier = dir.join(piece_file_name(1, 2));
        std::fs::write(&earlier, [0u8; 8]).unwrap();
        written.write(&dir).unwrap();
        assert!(
            !earlier.exists(),
            "the earlier checkpoint's piece is removed"
        );
        let read = Checkpoint::read(&dir, &written.identity).unwrap();
        assert_eq!(read, written);
        let pieces = read.pieces.as_ref().unwrap();
        for (piece, values) in pieces.files.iter().zip(&numbers) {
            assert_eq!(&read_piece(pieces, piece).unwrap(), values);
        }
        let why = read.needs_decomposition(&dir).unwrap();
        assert!(
            why.contains("2 pieces") && why.contains("--decompose --resume"),
            "{why}"
        );
        assert!(sample().needs_decomposition(&dir).is_none());

        let second = dir.join(piece_file_name(3, 1));
        let bytes = std::fs::read(&second).unwrap();
        let mut damaged = bytes.clone();
        damaged[3] ^= 1;
        std::fs::write(&second, &damaged).unwrap();
        let why = read_piece(pieces, &pieces.files[1]).unwrap_err();
        assert!(
            why.contains("checkpoint_0003_p1.bin does not have the hash"),
            "{why}"
        );
        std::fs::write(&second, &bytes[..8]).unwrap();
        let why = Checkpoint::read(&dir, &written.identity).unwrap_err();
        assert!(
            why.contains("checkpoint_0003_p1.bin is 8 bytes long") && why.contains("truncated"),
            "{why}"
        );
        std::fs::remove_file(&second).unwrap();
        let why = Checkpoint::read(&dir, &written.identity).unwrap_err();
        assert!(
            why.contains("cannot read") && why.contains("checkpoint_0003_p1.bin"),
            "{why}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
