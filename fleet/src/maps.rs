//! Site maps over the fleet link: a robot (or a fleet server) serves `.glintmap` files as Zenoh
//! queryables, and a new robot fetches one from whichever peer serves it.
//!
//! The transfer is chunked so that no hop holds more than one chunk per query and a broken
//! link costs one chunk's retry, not the whole file. A query on `glint/<site>/maps/<name>`
//! without parameters describes the file (the reply's attachment is
//! `size=<bytes>;crc=<file CRC-32, hex>;chunk=<bytes>`); with `offset=N;len=M` it returns those
//! bytes with the attachment `size=…;crc=…;chunk_crc=<the chunk's CRC-32, hex>`. The file's
//! CRC-32 is the one the `.glintmap` ends with: it names the version of the file, so a map
//! replaced on the server during a transfer is noticed and the transfer restarts. The fetched
//! bytes replace the local file only after `glint_map::install` has verified them as a whole,
//! valid map.

use std::collections::HashMap;
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use glint_map::{MapCounts, MapError};
use thiserror::Error;
use zenoh::query::{ConsolidationMode, Query, Queryable};
use zenoh::{Session, Wait};

use crate::keys::{FleetKeys, KeyError};

/// Largest chunk a server returns and the size a fetch asks for, bytes.
pub const MAP_CHUNK_BYTES: u64 = 1 << 20;

/// Largest map a fetch accepts, bytes: the whole file is held in memory to be verified before
/// it is installed. An hour of mapping makes about 34 MB.
const MAX_MAP_BYTES: u64 = 1 << 30;

/// Serves map files as queryables for as long as it lives.
pub struct MapServer {
    served: Vec<(String, PathBuf)>,
    _queryables: Vec<Queryable<()>>,
}

impl MapServer {
    /// Serves each file in `maps` under `glint/<site>/maps/<file stem>`. The files are read at
    /// each query, so a map saved again (atomically replaced) is served in its new version.
    pub fn serve(session: &Session, site: &str, maps: &[PathBuf]) -> Result<Self, ServeError> {
        let mut served = Vec::new();
        let mut queryables = Vec::new();
        for path in maps {
            let name = path
                .file_stem()
                .and_then(|s| s.to_str())
                .ok_or_else(|| ServeError::Name(path.clone()))?;
            let key = FleetKeys::map_file(site, name)?;
            let file = path.clone();
            let queryable = session
                .declare_queryable(key.clone())
                .complete(true)
                .callback(move |query| answer(&query, &file))
                .wait()
                .map_err(|e| ServeError::Zenoh(e.to_string()))?;
            served.push((key, path.clone()));
            queryables.push(queryable);
        }
        Ok(Self {
            served,
            _queryables: queryables,
        })
    }

    /// The keys served and their files.
    pub fn served(&self) -> &[(String, PathBuf)] {
        &self.served
    }
}

/// Why maps could not be served.
#[derive(Debug, Error)]
pub enum ServeError {
    /// The file name gives no usable map name.
    #[error("cannot name the map {}: its file stem is not UTF-8", .0.display())]
    Name(PathBuf),
    /// The map name is not a valid key chunk.
    #[error(transparent)]
    Key(#[from] KeyError),
    /// Zenoh refused the queryable.
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// What a map file is now: its length and the CRC-32 it ends with.
fn describe(file: &File) -> io::Result<(u64, u32)> {
    let size = file.metadata()?.len();
    if size < 4 {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            "shorter than a map",
        ));
    }
    let mut trailer = [0u8; 4];
    file.read_exact_at(&mut trailer, size - 4)?;
    Ok((size, u32::from_le_bytes(trailer)))
}

fn answer(query: &Query, path: &Path) {
    let reply = (|| -> Result<(Vec<u8>, String), String> {
        let file = File::open(path).map_err(|e| format!("cannot open the map: {e}"))?;
        let (size, crc) = describe(&file).map_err(|e| format!("cannot read the map: {e}"))?;
        let parameters = query.parameters();
        let Some(offset) = parameters.get("offset") else {
            return Ok((
                Vec::new(),
                format!("size={size};crc={crc:08x};chunk={MAP_CHUNK_BYTES}"),
            ));
        };
        let offset: u64 = offset.parse().map_err(|_| "offset is not a number")?;
        let len: u64 = parameters
            .get("len")
            .unwrap_or("0")
            .parse()
            .map_err(|_| "len is not a number")?;
        if offset > size {
            return Err(format!("offset {offset} is past the end ({size} bytes)"));
        }
        let len = len.min(MAP_CHUNK_BYTES).min(size - offset);
        let mut chunk = vec![0u8; len as usize];
        file.read_exact_at(&mut chunk, offset)
            .map_err(|e| format!("cannot read the map: {e}"))?;
        let chunk_crc = crc32fast::hash(&chunk);
        Ok((
            chunk,
            format!("size={size};crc={crc:08x};chunk_crc={chunk_crc:08x}"),
        ))
    })();
    // A failed reply is the querier's timeout to handle; nothing to do here.
    let _ = match reply {
        Ok((payload, attachment)) => query
            .reply(query.key_expr().clone(), payload)
            .attachment(attachment)
            .wait(),
        Err(message) => query.reply_err(message).wait(),
    };
}

/// Why a map could not be fetched. The local file is unchanged in every case.
#[derive(Debug, Error)]
pub enum FetchError {
    /// The map name is not a valid key chunk.
    #[error(transparent)]
    Key(#[from] KeyError),
    /// No peer answered for the map before the timeout.
    #[error("no peer serves {key} (waited {seconds:.0} s)")]
    NotServed {
        /// The key asked for.
        key: String,
        /// How long the fetch waited.
        seconds: f64,
    },
    /// The serving peer answered with an error.
    #[error("the peer serving {key} answered: {message}")]
    Refused {
        /// The key asked for.
        key: String,
        /// The peer's message.
        message: String,
    },
    /// A reply that does not follow the protocol, or a chunk that arrived damaged too often.
    #[error("{key}: {reason}")]
    Transfer {
        /// The key asked for.
        key: String,
        /// What went wrong.
        reason: String,
    },
    /// The bytes received are not a whole, valid map (or the local file could not be written).
    #[error("the map received for {key} was refused: {error}")]
    Invalid {
        /// The key asked for.
        key: String,
        /// What `glint_map` found.
        #[source]
        error: MapError,
    },
    /// Zenoh could not send the query.
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// What a fetch brought.
#[derive(Debug, Clone)]
pub struct FetchReport {
    /// The key fetched.
    pub key: String,
    /// Bytes of the map.
    pub bytes: u64,
    /// Chunks transferred (retries included).
    pub chunks: usize,
    /// Seconds from the first query to the file installed.
    pub seconds: f64,
    /// What the installed map holds.
    pub counts: MapCounts,
}

/// One reply: its payload and attachment fields.
struct Answer {
    payload: Vec<u8>,
    fields: HashMap<String, String>,
}

impl Answer {
    fn hex(&self, field: &str) -> Option<u32> {
        u32::from_str_radix(self.fields.get(field)?, 16).ok()
    }

    fn number(&self, field: &str) -> Option<u64> {
        self.fields.get(field)?.parse().ok()
    }
}

/// Asks `selector` once and returns the first good reply, `Ok(None)` when none came in time.
fn ask(
    session: &Session,
    key: &str,
    selector: &str,
    timeout: Duration,
) -> Result<Option<Answer>, FetchError> {
    let replies = session
        .get(selector)
        .consolidation(ConsolidationMode::None)
        .timeout(timeout)
        .wait()
        .map_err(|e| FetchError::Zenoh(e.to_string()))?;
    let mut refusal = None;
    while let Ok(reply) = replies.recv() {
        match reply.result() {
            Ok(sample) => {
                let fields = sample
                    .attachment()
                    .and_then(|a| a.try_to_string().ok())
                    .map(|text| {
                        text.split(';')
                            .filter_map(|kv| kv.split_once('='))
                            .map(|(k, v)| (k.to_string(), v.to_string()))
                            .collect()
                    })
                    .unwrap_or_default();
                return Ok(Some(Answer {
                    payload: sample.payload().to_bytes().into_owned(),
                    fields,
                }));
            }
            Err(error) => {
                let message = error.payload().try_to_string().map(|s| s.into_owned());
                // Zenoh reports its own timeout as an error reply too; only a peer's counts.
                if let Ok(m) = message {
                    if m != "Timeout" {
                        refusal = Some(m);
                    }
                }
            }
        }
    }
    match refusal {
        Some(message) => Err(FetchError::Refused {
            key: key.to_string(),
            message,
        }),
        None => Ok(None),
    }
}

/// Fetches map `name` of `site` from any peer serving it and installs it at `out` once it is
/// verified. Waits up to `timeout` for a peer to answer, and as long again for each chunk.
pub fn fetch_map(
    session: &Session,
    site: &str,
    name: &str,
    out: &Path,
    timeout: Duration,
) -> Result<FetchReport, FetchError> {
    let key = FleetKeys::map_file(site, name)?;
    let started = Instant::now();
    let transfer = |reason: String| FetchError::Transfer {
        key: key.clone(),
        reason,
    };
    let mut chunks = 0;
    // A map replaced on the server mid-transfer restarts the transfer, a few times at most.
    for _attempt in 0..3 {
        let description = loop {
            let left = timeout.saturating_sub(started.elapsed());
            if let Some(d) = ask(session, &key, &key, left.min(Duration::from_secs(2)))? {
                break d;
            }
            if started.elapsed() >= timeout {
                return Err(FetchError::NotServed {
                    key,
                    seconds: timeout.as_secs_f64(),
                });
            }
            std::thread::sleep(Duration::from_millis(200));
        };
        let (Some(size), Some(crc)) = (description.number("size"), description.hex("crc")) else {
            return Err(transfer("the description lacks size or crc".into()));
        };
        if size > MAX_MAP_BYTES {
            return Err(transfer(format!(
                "the map is {size} bytes, more than the {MAX_MAP_BYTES} accepted"
            )));
        }
        // Grown as chunks arrive rather than reserved from the size a peer claims.
        let mut bytes = Vec::with_capacity(size.min(64 << 20) as usize);
        let mut changed = false;
        while (bytes.len() as u64) < size {
            let offset = bytes.len() as u64;
            let selector = format!("{key}?offset={offset};len={MAP_CHUNK_BYTES}");
            let mut tries = 0;
            let chunk = loop {
                tries += 1;
                chunks += 1;
                let answer = ask(session, &key, &selector, timeout)?;
                let good = answer.filter(|a| {
                    a.hex("chunk_crc") == Some(crc32fast::hash(&a.payload)) && !a.payload.is_empty()
                });
                match good {
                    Some(a) => break a,
                    None if tries < 3 => continue,
                    None => {
                        return Err(transfer(format!(
                            "the chunk at byte {offset} did not arrive intact in 3 tries"
                        )))
                    }
                }
            };
            if chunk.hex("crc") != Some(crc) || chunk.number("size") != Some(size) {
                changed = true;
                break;
            }
            let end = (offset + chunk.payload.len() as u64).min(size) as usize;
            bytes.extend_from_slice(&chunk.payload[..end - offset as usize]);
        }
        if changed {
            continue;
        }
        let counts = glint_map::install(out, &bytes).map_err(|error| FetchError::Invalid {
            key: key.clone(),
            error,
        })?;
        return Ok(FetchReport {
            key,
            bytes: size,
            chunks,
            seconds: started.elapsed().as_secs_f64(),
            counts,
        });
    }
    Err(transfer(
        "the map changed on the server during three transfers in a row".into(),
    ))
}
