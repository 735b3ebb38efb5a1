"""The scenes shipped with mbdfmu (TOML files; see the README for the format)."""
