//! The fleet link's settings and the Zenoh session they open: where to listen and connect,
//! TLS (with client certificates for mutual TLS), access control, and nothing left to Zenoh's
//! defaults that would surprise a site's network administrator: no listening on every
//! interface unless asked, no multicast scouting once endpoints are given, and plain TCP only
//! when asked for explicitly.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::Deserialize;
use thiserror::Error;
use zenoh::{Config, Session, Wait};

/// How the session joins the fleet's network (Zenoh's `mode`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Talks to the peers and routers it connects to or that connect to it.
    #[default]
    Peer,
    /// Talks through the router(s) it connects to only.
    Client,
}

/// TLS settings. With them every endpoint must be `tls/…` and the session refuses plain TCP.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsConfig {
    /// The CA certificate (PEM) the other side's certificate must chain to; with `mutual`, also
    /// the CA of the clients' certificates.
    pub root_ca: PathBuf,
    /// This side's certificate chain (PEM): presented when listening, and as the client
    /// certificate when connecting with `mutual`.
    #[serde(default)]
    pub certificate: Option<PathBuf>,
    /// The private key of `certificate` (PEM: PKCS#8, PKCS#1 or SEC1).
    #[serde(default)]
    pub private_key: Option<PathBuf>,
    /// Mutual TLS: a listener accepts only clients with a certificate from `root_ca`, and
    /// connecting presents `certificate`. Both ends must set it.
    #[serde(default)]
    pub mutual: bool,
    /// Check that the server's certificate names the host of the endpoint connected to.
    #[serde(default = "yes")]
    pub verify_name: bool,
}

fn yes() -> bool {
    true
}

/// Where and how a process joins the fleet link.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkConfig {
    /// Peer (default) or client.
    #[serde(default)]
    pub mode: Mode,
    /// Endpoints to listen on, in Zenoh's syntax (`tls/0.0.0.0:7447`). None by default.
    #[serde(default)]
    pub listen: Vec<String>,
    /// Endpoints (peers or routers) to connect to; retried while unreachable.
    #[serde(default)]
    pub connect: Vec<String>,
    /// Allow plain TCP without TLS (a bench, a closed network). Logged as a warning.
    #[serde(default)]
    pub insecure: bool,
    /// TLS; required unless `insecure`.
    #[serde(default)]
    pub tls: Option<TlsConfig>,
    /// Zenoh's access control, in Zenoh's own schema (`enabled`, `default_permission`, `rules`,
    /// `subjects`, `policies`), passed through unchanged.
    #[serde(default)]
    pub access_control: Option<serde_json::Value>,
}

/// Why the link could not be set up.
#[derive(Debug, Error)]
pub enum LinkError {
    /// Neither TLS settings nor an explicit request for plain TCP.
    #[error(
        "no [tls] settings: the fleet link would carry poses and maps in clear text; configure \
         TLS (docs/fleet.md) or pass --insecure for plain TCP"
    )]
    NoTls,
    /// An endpoint of a protocol the link does not use with these settings.
    #[error("endpoint {endpoint:?}: {reason}")]
    Endpoint {
        /// The endpoint as given.
        endpoint: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A setting is missing or contradicts another.
    #[error("{0}")]
    Setting(String),
    /// A certificate or key file is missing, unreadable or not PEM.
    #[error("TLS {what} {}: {reason}", path.display())]
    Pem {
        /// Which file: root CA, certificate or private key.
        what: &'static str,
        /// Its path.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Zenoh refused the configuration or could not open the session (a listener's port in
    /// use, a bad certificate…).
    #[error("zenoh: {0}")]
    Zenoh(String),
}

impl LinkConfig {
    /// Whether the link runs in clear text (allowed by `insecure`, no TLS settings).
    pub fn is_plain(&self) -> bool {
        self.tls.is_none()
    }

    /// Checks the settings against each other and the certificate files, and builds the Zenoh
    /// configuration.
    pub fn zenoh_config(&self) -> Result<Config, LinkError> {
        let protocol = match (&self.tls, self.insecure) {
            (Some(_), _) => "tls",
            (None, true) => "tcp",
            (None, false) => return Err(LinkError::NoTls),
        };
        for endpoint in self.listen.iter().chain(&self.connect) {
            let Some((given, _)) = endpoint.split_once('/') else {
                return Err(LinkError::Endpoint {
                    endpoint: endpoint.clone(),
                    reason: "not in Zenoh's syntax PROTOCOL/ADDRESS:PORT",
                });
            };
            if given != protocol {
                return Err(LinkError::Endpoint {
                    endpoint: endpoint.clone(),
                    reason: if protocol == "tls" {
                        "with [tls] configured every endpoint must be tls/…"
                    } else {
                        "without [tls] the link offers only tcp/… endpoints"
                    },
                });
            }
        }
        if self.mode == Mode::Client && self.connect.is_empty() {
            return Err(LinkError::Setting(
                "mode \"client\" needs at least one endpoint to connect to".into(),
            ));
        }
        let mut config = Config::default();
        let mut set = |key: &str, value: serde_json::Value| {
            config
                .insert_json5(key, &value.to_string())
                .map_err(|e| LinkError::Zenoh(format!("setting {key}: {e}")))
        };
        set(
            "mode",
            serde_json::json!(match self.mode {
                Mode::Peer => "peer",
                Mode::Client => "client",
            }),
        )?;
        set("listen/endpoints", serde_json::json!(self.listen))?;
        set("connect/endpoints", serde_json::json!(self.connect))?;
        if !self.listen.is_empty() || !self.connect.is_empty() {
            set("scouting/multicast/enabled", serde_json::json!(false))?;
        }
        set("transport/link/protocols", serde_json::json!([protocol]))?;
        if let Some(tls) = &self.tls {
            set("transport/link/tls", self.tls_settings(tls)?)?;
        }
        if let Some(acl) = &self.access_control {
            set("access_control", acl.clone())?;
        }
        Ok(config)
    }

    fn tls_settings(&self, tls: &TlsConfig) -> Result<serde_json::Value, LinkError> {
        let mut settings = serde_json::Map::new();
        let path = |p: &Path| serde_json::json!(p.to_string_lossy());
        check_pem("root CA", &tls.root_ca, "CERTIFICATE")?;
        settings.insert("root_ca_certificate".into(), path(&tls.root_ca));
        let own = match (&tls.certificate, &tls.private_key) {
            (Some(c), Some(k)) => {
                check_pem("certificate", c, "CERTIFICATE")?;
                check_pem("private key", k, "PRIVATE KEY")?;
                Some((c, k))
            }
            (None, None) => None,
            _ => {
                return Err(LinkError::Setting(
                    "[tls] certificate and private_key go together".into(),
                ))
            }
        };
        if own.is_none() && (!self.listen.is_empty() || tls.mutual) {
            return Err(LinkError::Setting(
                "[tls] certificate and private_key are needed to listen or for mutual TLS".into(),
            ));
        }
        if let Some((c, k)) = own {
            settings.insert("listen_certificate".into(), path(c));
            settings.insert("listen_private_key".into(), path(k));
            if tls.mutual {
                settings.insert("connect_certificate".into(), path(c));
                settings.insert("connect_private_key".into(), path(k));
            }
        }
        settings.insert("enable_mtls".into(), serde_json::json!(tls.mutual));
        settings.insert(
            "verify_name_on_connect".into(),
            serde_json::json!(tls.verify_name),
        );
        Ok(serde_json::Value::Object(settings))
    }
}

/// Refuses a file that cannot be read or holds no PEM block of `label` (Zenoh reads the files
/// only when a link opens, and a connecting peer would only log its failure and retry).
fn check_pem(what: &'static str, path: &Path, label: &str) -> Result<(), LinkError> {
    let text = std::fs::read_to_string(path).map_err(|e| LinkError::Pem {
        what,
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let found = text.lines().any(|line| {
        line.trim()
            .strip_prefix("-----BEGIN ")
            .is_some_and(|rest| rest.trim_end_matches("-----").ends_with(label))
    });
    if !found {
        return Err(LinkError::Pem {
            what,
            path: path.to_path_buf(),
            reason: format!("no PEM {label} block"),
        });
    }
    Ok(())
}

/// Opens the Zenoh session `link` describes.
pub fn open(link: &LinkConfig) -> Result<Session, LinkError> {
    let config = link.zenoh_config()?;
    zenoh::open(config)
        .wait()
        .map_err(|e| LinkError::Zenoh(e.to_string()))
}

/// Waits until the session has a peer or router, or `timeout` passes; returns whether it has.
pub fn wait_connected(session: &Session, timeout: Duration) -> bool {
    let until = Instant::now() + timeout;
    loop {
        let info = session.info();
        if info.routers_zid().wait().next().is_some() || info.peers_zid().wait().next().is_some() {
            return true;
        }
        if Instant::now() >= until {
            return false;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plain(listen: &[&str]) -> LinkConfig {
        LinkConfig {
            listen: listen.iter().map(|s| s.to_string()).collect(),
            insecure: true,
            ..LinkConfig::default()
        }
    }

    #[test]
    fn without_tls_the_link_needs_an_explicit_insecure() {
        let mut link = plain(&["tcp/127.0.0.1:7447"]);
        assert!(link.zenoh_config().is_ok());
        link.insecure = false;
        assert!(matches!(link.zenoh_config(), Err(LinkError::NoTls)));
    }

    #[test]
    fn endpoints_must_match_the_security_chosen() {
        assert!(matches!(
            plain(&["tls/127.0.0.1:7447"]).zenoh_config(),
            Err(LinkError::Endpoint { .. })
        ));
        assert!(matches!(
            plain(&["udp/127.0.0.1:7447"]).zenoh_config(),
            Err(LinkError::Endpoint { .. })
        ));
        let dir = std::env::temp_dir().join(format!("glint-fleet-link-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ca = dir.join("ca.pem");
        std::fs::write(
            &ca,
            "-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n",
        )
        .unwrap();
        let link = LinkConfig {
            connect: vec!["tcp/127.0.0.1:7447".into()],
            tls: Some(TlsConfig {
                root_ca: ca.clone(),
                certificate: None,
                private_key: None,
                mutual: false,
                verify_name: true,
            }),
            ..LinkConfig::default()
        };
        assert!(matches!(
            link.zenoh_config(),
            Err(LinkError::Endpoint { .. })
        ));
        let tls_link = LinkConfig {
            connect: vec!["tls/localhost:7447".into()],
            ..link.clone()
        };
        assert!(tls_link.zenoh_config().is_ok());
        // Listening needs this side's certificate.
        let listening = LinkConfig {
            listen: vec!["tls/127.0.0.1:7447".into()],
            ..tls_link.clone()
        };
        assert!(matches!(
            listening.zenoh_config(),
            Err(LinkError::Setting(_))
        ));
        let missing = LinkConfig {
            tls: Some(TlsConfig {
                root_ca: dir.join("absent.pem"),
                certificate: None,
                private_key: None,
                mutual: false,
                verify_name: true,
            }),
            ..tls_link
        };
        assert!(matches!(missing.zenoh_config(), Err(LinkError::Pem { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_toml_form_parses_with_access_control_passed_through() {
        let link: LinkConfig = toml::from_str(
            r#"
            mode = "client"
            connect = ["tls/fleet.example:7447"]
            [tls]
            root_ca = "/etc/glint/fleet-ca.pem"
            certificate = "/etc/glint/robot.pem"
            private_key = "/etc/glint/robot.key"
            mutual = true
            [access_control]
            enabled = true
            default_permission = "deny"
            rules = [{ id = "maps", messages = ["query", "reply"], key_exprs = ["glint/*/maps/**"], permission = "allow" }]
            subjects = [{ id = "fleet", cert_common_names = ["fleet-server"] }]
            policies = [{ rules = ["maps"], subjects = ["fleet"] }]
            "#,
        )
        .unwrap();
        assert_eq!(link.mode, Mode::Client);
        assert!(link.tls.as_ref().unwrap().mutual && link.tls.as_ref().unwrap().verify_name);
        let acl = link.access_control.unwrap();
        assert_eq!(acl["subjects"][0]["cert_common_names"][0], "fleet-server");
    }
}
