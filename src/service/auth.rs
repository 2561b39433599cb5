//! Who may do what. A tokens file (TOML) holds each token's SHA-256 digest, never the token,
//! with a name and a role: observer (read, events, live view) < operator (queue, run control,
//! jog) < admin (locks, shutdown). A request carries `Authorization: Bearer TOKEN`.
//!
//! ```toml
//! [[token]]
//! name = "lab-pc"
//! role = "operator"
//! sha256 = "…64 hex digits…"
//! ```
//!
//! `rig serve token add NAME --role ROLE --tokens FILE` makes one and prints it once.

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    Observer,
    Operator,
    Admin,
}

impl Role {
    pub fn name(self) -> &'static str {
        match self {
            Role::Observer => "observer",
            Role::Operator => "operator",
            Role::Admin => "admin",
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Token {
    pub name: String,
    pub role: Role,
    /// SHA-256 of the token, hex.
    pub sha256: String,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tokens {
    #[serde(default, rename = "token")]
    pub tokens: Vec<Token>,
}

#[derive(Debug, thiserror::Error)]
pub enum AuthError {
    #[error("cannot read the tokens file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

pub fn digest(token: &str) -> String {
    let d = Sha256::digest(token.as_bytes());
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// Compares without stopping at the first difference, so the time taken says nothing of how
/// much of a guess was right.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

impl Tokens {
    pub fn load(path: &Path) -> Result<Tokens, AuthError> {
        let text = std::fs::read_to_string(path).map_err(|source| AuthError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Tokens, AuthError> {
        let invalid = |message: String| AuthError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let t: Tokens = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        for (i, k) in t.tokens.iter().enumerate() {
            if k.sha256.len() != 64 || !k.sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
                return Err(invalid(format!(
                    "token {} ({:?}): sha256 must be 64 hex digits (the digest `rig serve token add` writes), not the token itself",
                    i + 1,
                    k.name
                )));
            }
            if k.name.is_empty() || k.name.len() > 100 {
                return Err(invalid(format!(
                    "token {}: a name of 1 to 100 characters",
                    i + 1
                )));
            }
        }
        Ok(t)
    }

    /// The file's text: what [`Tokens::parse`] reads.
    pub fn to_toml(&self) -> String {
        let mut s =
            String::from("# rig serve's tokens: SHA-256 digests only (`rig serve token add`).\n");
        for t in &self.tokens {
            s += &format!(
                "\n[[token]]\nname = {:?}\nrole = \"{}\"\nsha256 = \"{}\"\n",
                t.name,
                t.role.name(),
                t.sha256
            );
        }
        s
    }

    pub fn is_empty(&self) -> bool {
        self.tokens.is_empty()
    }

    /// The token's entry, if it is one of these.
    pub fn check(&self, token: &str) -> Option<&Token> {
        let d = digest(token);
        let mut found = None;
        for t in &self.tokens {
            if same(t.sha256.to_ascii_lowercase().as_bytes(), d.as_bytes()) {
                found = Some(t);
            }
        }
        found
    }

    /// A new random token for `name` with `role`: added here, returned in clear (shown once).
    pub fn add(&mut self, name: &str, role: Role) -> std::io::Result<String> {
        let mut bytes = [0u8; 24];
        std::io::Read::read_exact(&mut std::fs::File::open("/dev/urandom")?, &mut bytes)?;
        let token: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        self.tokens.retain(|t| t.name != name);
        self.tokens.push(Token {
            name: name.to_string(),
            role,
            sha256: digest(&token),
        });
        Ok(token)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_is_found_by_its_digest_and_a_clear_token_in_the_file_is_refused() {
        let mut t = Tokens::default();
        let a = t.add("a", Role::Operator).unwrap();
        let b = t.add("b", Role::Admin).unwrap();
        assert_ne!(a, b);
        assert_eq!(t.check(&a).unwrap().role, Role::Operator);
        assert_eq!(t.check(&b).unwrap().role, Role::Admin);
        assert!(t.check("").is_none());
        assert!(t.check(&a[1..]).is_none());
        // The digest is SHA-256 (FIPS 180-2's "abc" example).
        assert_eq!(
            digest("abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let text = t.to_toml();
        assert!(!text.contains(&a));
        let back = Tokens::parse(&text, Path::new("t.toml")).unwrap();
        assert_eq!(back.check(&b).unwrap().name, "b");
        let clear = format!("[[token]]\nname = \"x\"\nrole = \"admin\"\nsha256 = \"{a}\"\n");
        let e = Tokens::parse(&clear, Path::new("t.toml")).unwrap_err();
        assert!(e.to_string().contains("64 hex digits"), "{e}");
        assert!(Tokens::parse(
            "[[token]]\nname = \"x\"\nrole = \"king\"\nsha256 = \"00\"\n",
            Path::new("t.toml")
        )
        .is_err());
        assert!(Role::Observer < Role::Operator && Role::Operator < Role::Admin);
    }
}
