"""What the run and the clip viewers' servers share: importing viser with an error that says how to
install it, and the warning for a server listening beyond this machine."""

from __future__ import annotations

from typing import Optional

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def import_viser():
    """The viser module, or an error saying how to install it (the `viewer` extra)."""
    try:
        import viser
    except ImportError as e:
        from m4dgs.core.errors import InputError

        raise InputError(
            f"m4dgs view needs the viser package ({e}); install it with: pip install -e "
            '".[viewer]" (or pip install viser==1.1.1)'
        ) from None
    return viser


def exposure_warning(host: str) -> Optional[str]:
    """The warning printed when the viewer listens beyond this machine, None for loopback."""
    if host in LOOPBACK:
        return None
    return (
        f"warning: the viewer listens on {host}: anyone who can reach this machine on that "
        "network can connect and see the run (it serves the viewer page only; no login). Use "
        "--host 127.0.0.1 (the default) and an SSH tunnel to keep it private."
    )
