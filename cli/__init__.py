"""The click front end of avatarkit (installed as `avatarkit.cli`). Thin: parse, call, report."""
