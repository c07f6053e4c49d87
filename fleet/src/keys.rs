//! The fleet's key expressions and the attachment that names a payload's type.
//!
//! A robot publishes under `glint/<site>/<robot>/odom`, `…/map` and `…/status`; site maps are
//! served under `glint/<site>/maps/<name>`. Site, robot and map names are single key chunks of
//! letters, digits, `-`, `_` and `.`, so no name can add a chunk or a wildcard, and no robot
//! may be called `maps` (its streams would collide with maps named `odom`, `map` or `status`).

use thiserror::Error;

/// Why a site, robot or map name was refused.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum KeyError {
    /// Empty or longer than [`FleetKeys::MAX_NAME_LEN`].
    #[error("the {what} name must be 1 to {max} characters long, got {len}", max = FleetKeys::MAX_NAME_LEN)]
    Length {
        /// Which name: site, robot or map.
        what: &'static str,
        /// Its length in bytes.
        len: usize,
    },
    /// A character outside letters, digits, `-`, `_` and `.`.
    #[error("the {what} name {name:?} may hold only letters, digits, '-', '_' and '.'")]
    Character {
        /// Which name.
        what: &'static str,
        /// The refused name.
        name: String,
    },
    /// A robot called `maps`.
    #[error("a robot cannot be called \"maps\": glint/<site>/maps/ holds the site's maps")]
    Reserved,
}

fn check(what: &'static str, name: &str) -> Result<(), KeyError> {
    if name.is_empty() || name.len() > FleetKeys::MAX_NAME_LEN {
        return Err(KeyError::Length {
            what,
            len: name.len(),
        });
    }
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    if !name.chars().all(allowed) || name == "." || name == ".." {
        return Err(KeyError::Character {
            what,
            name: name.to_string(),
        });
    }
    Ok(())
}

/// A robot's place in the fleet's key space.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FleetKeys {
    site: String,
    robot: String,
}

/// What a published payload is, named in its attachment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PayloadType {
    /// `glint::PoseV1`, 424 bytes.
    Pose,
    /// `glint::StatusV1`, 80 bytes.
    Status,
}

impl PayloadType {
    /// The attachment sent with every sample: the shared-memory type name and its layout
    /// version, as UTF-8 `type=<name>;version=<n>`.
    pub const fn attachment(self) -> &'static str {
        match self {
            Self::Pose => "type=glint::PoseV1;version=1",
            Self::Status => "type=glint::StatusV1;version=1",
        }
    }
}

impl FleetKeys {
    /// Longest site, robot or map name, bytes.
    pub const MAX_NAME_LEN: usize = 64;

    /// The keys of robot `robot` at site `site`.
    pub fn new(site: &str, robot: &str) -> Result<Self, KeyError> {
        check("site", site)?;
        check("robot", robot)?;
        if robot == "maps" {
            return Err(KeyError::Reserved);
        }
        Ok(Self {
            site: site.to_string(),
            robot: robot.to_string(),
        })
    }

    /// The site's name.
    pub fn site(&self) -> &str {
        &self.site
    }

    /// The robot's name.
    pub fn robot(&self) -> &str {
        &self.robot
    }

    /// `glint/<site>/<robot>/<stream>` for `odom`, `map` or `status`.
    pub fn stream(&self, stream: &str) -> String {
        format!("glint/{}/{}/{stream}", self.site, self.robot)
    }

    /// `glint/<site>/maps/<name>`: where the site map `name` is served.
    pub fn map_file(site: &str, name: &str) -> Result<String, KeyError> {
        check("site", site)?;
        check("map", name)?;
        Ok(format!("glint/{site}/maps/{name}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_built_from_checked_names() {
        let keys = FleetKeys::new("dc-berlin", "agv-07").unwrap();
        assert_eq!(keys.stream("odom"), "glint/dc-berlin/agv-07/odom");
        assert_eq!(
            FleetKeys::map_file("dc-berlin", "hall_2.v3").unwrap(),
            "glint/dc-berlin/maps/hall_2.v3"
        );
    }

    #[test]
    fn names_that_would_add_chunks_or_wildcards_are_refused() {
        for bad in [
            "",
            "a/b",
            "*",
            "**",
            "a$",
            "x?y",
            "@admin",
            "..",
            "robot one",
        ] {
            assert!(FleetKeys::new("site", bad).is_err(), "{bad:?}");
            assert!(FleetKeys::map_file(bad, "m").is_err(), "{bad:?}");
        }
        assert_eq!(FleetKeys::new("site", "maps"), Err(KeyError::Reserved));
        assert!(FleetKeys::new("site", &"r".repeat(65)).is_err());
    }
}
