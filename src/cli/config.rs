//! The operator's everyday settings — the stage's port and dialect, the camera — from a flag,
//! the environment (`RIG_STAGE`, `RIG_DIALECT`, `RIG_CAMERA`) or `rig.toml` (in the working
//! directory, else `$XDG_CONFIG_HOME/rig/rig.toml` or `~/.config/rig/rig.toml`; keys `stage`,
//! `dialect`, `camera`), in that order of precedence; `rig config show` shows what wins and why.

use anyhow::{bail, Context};
use clap::ValueEnum;
use rig::stage::Dialect;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The file's keys; any other key is refused by name.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    stage: Option<PathBuf>,
    dialect: Option<String>,
    camera: Option<String>,
}

/// Where a setting came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    Flag,
    Env(String),
    File(PathBuf),
    Default,
    NotSet,
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            Source::Flag => write!(f, "flag"),
            Source::Env(v) => write!(f, "environment {v}"),
            Source::File(p) => write!(f, "{}", p.display()),
            Source::Default => write!(f, "default"),
            Source::NotSet => write!(f, "not set"),
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Setting<T> {
    pub value: Option<T>,
    pub source: Source,
}

/// The settings in force, and the files looked at.
#[derive(Debug, Clone, Serialize)]
pub struct Resolved {
    pub stage: Setting<PathBuf>,
    pub dialect: Setting<Dialect>,
    pub camera: Setting<String>,
    /// Each candidate file and whether it was read.
    pub files: Vec<(PathBuf, bool)>,
}

impl Resolved {
    pub fn dialect(&self) -> Dialect {
        self.dialect.value.unwrap_or(Dialect::Native)
    }
}

/// The candidate files, first found wins: ./rig.toml, then the user's config directory.
fn candidates() -> Vec<PathBuf> {
    let mut v = vec![PathBuf::from("rig.toml")];
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .filter(|s| !s.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".config")));
    if let Some(b) = base {
        v.push(b.join("rig").join("rig.toml"));
    }
    v
}

fn parse_dialect(v: &str, what: &str) -> anyhow::Result<Dialect> {
    Dialect::from_str(v.trim(), true)
        .map_err(|_| anyhow::anyhow!("{what} = {v:?}: the dialect is native or grbl"))
}

/// Resolves the settings: flags (`port`, `camera`) over the environment over the file.
pub fn resolve(
    stage_flag: Option<&PathBuf>,
    dialect_flag: Option<Dialect>,
    camera_flag: Option<&String>,
) -> anyhow::Result<Resolved> {
    let mut files = Vec::new();
    let mut file = None;
    for c in candidates() {
        let found = c.is_file();
        if found && file.is_none() {
            let text =
                std::fs::read_to_string(&c).with_context(|| format!("reading {}", c.display()))?;
            let f: FileConfig = toml::from_str(&text)
                .with_context(|| format!("{}: keys are stage, dialect, camera", c.display()))?;
            // Named by its full path, so the operator sees which file it was.
            let c = std::fs::canonicalize(&c).unwrap_or(c);
            file = Some((c.clone(), f));
            files.push((c, true));
        } else {
            files.push((c, false));
        }
    }
    let env = |k: &str| std::env::var(k).ok().filter(|v| !v.trim().is_empty());
    let from_file = |get: &dyn Fn(&FileConfig) -> Option<String>| {
        file.as_ref()
            .and_then(|(p, f)| get(f).map(|v| (v, Source::File(p.clone()))))
    };
    // stage
    let stage = match (stage_flag, env("RIG_STAGE")) {
        (Some(p), _) => Setting {
            value: Some(p.clone()),
            source: Source::Flag,
        },
        (None, Some(v)) => Setting {
            value: Some(PathBuf::from(v)),
            source: Source::Env("RIG_STAGE".into()),
        },
        (None, None) => match from_file(&|f| f.stage.as_ref().map(|p| p.display().to_string())) {
            Some((v, s)) => Setting {
                value: Some(PathBuf::from(v)),
                source: s,
            },
            None => Setting {
                value: None,
                source: Source::NotSet,
            },
        },
    };
    // dialect
    let dialect = match (dialect_flag, env("RIG_DIALECT")) {
        (Some(d), _) => Setting {
            value: Some(d),
            source: Source::Flag,
        },
        (None, Some(v)) => Setting {
            value: Some(parse_dialect(&v, "RIG_DIALECT")?),
            source: Source::Env("RIG_DIALECT".into()),
        },
        (None, None) => match from_file(&|f| f.dialect.clone()) {
            Some((v, s)) => {
                let what = format!("{s}: dialect");
                Setting {
                    value: Some(parse_dialect(&v, &what)?),
                    source: s,
                }
            }
            None => Setting {
                value: Some(Dialect::Native),
                source: Source::Default,
            },
        },
    };
    // camera
    let camera = match (camera_flag.cloned(), env("RIG_CAMERA")) {
        (Some(c), _) => Setting {
            value: Some(c),
            source: Source::Flag,
        },
        (None, Some(v)) => Setting {
            value: Some(v),
            source: Source::Env("RIG_CAMERA".into()),
        },
        (None, None) => match from_file(&|f| f.camera.clone()) {
            Some((v, s)) => Setting {
                value: Some(v),
                source: s,
            },
            None => Setting {
                value: None,
                source: Source::NotSet,
            },
        },
    };
    if let Some(p) = &stage.value {
        if p.as_os_str().is_empty() {
            bail!("the stage's port ({}) is empty", stage.source);
        }
    }
    Ok(Resolved {
        stage,
        dialect,
        camera,
        files,
    })
}

/// `rig config show`: the settings in force and where each comes from.
pub fn show(
    stage: Option<&PathBuf>,
    dialect: Option<Dialect>,
    camera: Option<&String>,
    json: bool,
) -> anyhow::Result<i32> {
    let r = resolve(stage, dialect, camera)?;
    if json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(rig::exit::OK);
    }
    let show = |v: Option<String>| v.unwrap_or_else(|| "-".into());
    println!(
        "stage    {:<24} ({})",
        show(r.stage.value.as_ref().map(|p| p.display().to_string())),
        r.stage.source
    );
    println!(
        "dialect  {:<24} ({})",
        show(r.dialect.value.map(|d| format!("{d:?}").to_lowercase())),
        r.dialect.source
    );
    println!(
        "camera   {:<24} ({})",
        show(r.camera.value.clone()),
        r.camera.source
    );
    for (f, read) in &r.files {
        println!(
            "file     {} ({})",
            f.display(),
            if *read { "read" } else { "not found" }
        );
    }
    println!("precedence: flag > environment (RIG_STAGE, RIG_DIALECT, RIG_CAMERA) > the first file found > default");
    Ok(rig::exit::OK)
}
