//! Tokens to roles.
//!
//! A viewer watches, a driver may also move dynamic objects, an admin may
//! do everything. In development mode (no tokens, `--dev`) everyone is an
//! admin; the server says so loudly at start-up and in every `Welcome`.

use std::collections::HashMap;

use anyhow::Result;
use lightwire_protocol::Role;

use super::config::Config;

/// Maps presented tokens to roles.
pub struct Auth {
    tokens: HashMap<String, Role>,
    dev_mode: bool,
}

impl Auth {
    pub fn from_config(config: &Config) -> Result<Self> {
        let mut tokens = HashMap::new();
        for (list, role) in [
            (&config.tokens.viewer, Role::Viewer),
            (&config.tokens.driver, Role::Driver),
            (&config.tokens.admin, Role::Admin),
        ] {
            for t in list {
                if t.len() < 8 {
                    anyhow::bail!(
                        "a {role:?} token is shorter than 8 characters; use a long random token"
                    );
                }
                tokens.insert(t.clone(), role);
            }
        }
        Ok(Self {
            tokens,
            dev_mode: config.dev_mode,
        })
    }

    /// The role a token grants, or `None` if it grants nothing.
    pub fn role(&self, token: Option<&str>) -> Option<Role> {
        if self.dev_mode && self.tokens.is_empty() {
            return Some(Role::Admin);
        }
        token.and_then(|t| self.tokens.get(t).copied())
    }

    pub fn dev_mode(&self) -> bool {
        self.dev_mode && self.tokens.is_empty()
    }
}

/// Whether a role may send transforms.
pub fn may_drive(role: Role) -> bool {
    matches!(role, Role::Driver | Role::Admin)
}
