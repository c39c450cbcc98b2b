//! Empty: see Cargo.toml (this package only pins openfx-sys's sources).
