"""Which Ray addresses gsgs will talk to: loopback freely, anything else only with token authentication.

Standard library only (the add-on checks its preference with the same rule before it starts a job).
A Ray cluster runs the code its clients send, so an unauthenticated head reachable from a network
is a remote-code-execution service; Ray >= 2.52 has token authentication (`RAY_AUTH_MODE=token`, the
token in `RAY_AUTH_TOKEN`, a file named by `RAY_AUTH_TOKEN_PATH`, or `~/.ray/auth_token`).
"""

from __future__ import annotations

import ipaddress
import os
import socket
from pathlib import Path

from gsgs_engine import GsgsError

HOW_TO_TOKEN = ("start the cluster with token authentication (`ray get-auth-token --generate`, then "
                "`RAY_AUTH_MODE=token ray start --head ...` on the head and every worker) and set RAY_AUTH_MODE=token "
                "and RAY_AUTH_TOKEN (or RAY_AUTH_TOKEN_PATH) here, or in the add-on's preferences (docs/cluster.md)")


def split_address(address: str) -> tuple[str, str, int | None]:
    """(scheme, host, port) of what `ray.init(address=...)` takes: HOST:PORT, ray://HOST:PORT, [v6]:PORT."""
    text = (address or "").strip()
    if not text:
        raise GsgsError("--ray needs an address: HOST:PORT of a Ray head (`ray start --head --port 6380`) "
                        "or ray://HOST:10001 (Ray Client)")
    scheme = ""
    if "://" in text:
        scheme, text = text.split("://", 1)
        if scheme != "ray":
            raise GsgsError(f"--ray {address!r}: only HOST:PORT and ray://HOST:PORT addresses are supported")
    text = text.rstrip("/")
    if text.startswith("["):  # [::1]:6380
        host, _, rest = text[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else ""
    elif text.count(":") == 1:
        host, port_text = text.split(":")
    else:
        host, port_text = text, ""
    if not host:
        raise GsgsError(f"--ray {address!r}: no host; use HOST:PORT, e.g. 127.0.0.1:6380")
    try:
        port = int(port_text) if port_text else None
    except ValueError as exc:
        raise GsgsError(f"--ray {address!r}: port {port_text!r} is not a number") from exc
    if port is not None and not 0 < port < 65536:
        raise GsgsError(f"--ray {address!r}: port {port} is out of range")
    return scheme, host, port


def is_loopback(host: str) -> bool:
    """True when every address `host` names is on this machine's loopback interface (127/8, ::1)."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    if host.lower() == "localhost":
        return True
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False  # unresolvable: not provably local
    return bool(infos) and all(ipaddress.ip_address(info[4][0].split("%")[0]).is_loopback for info in infos)


def token_configured(environ: dict | None = None) -> bool:
    """RAY_AUTH_MODE=token and a non-empty token where Ray looks for it."""
    env = os.environ if environ is None else environ
    if env.get("RAY_AUTH_MODE", "").strip().lower() != "token":
        return False
    if env.get("RAY_AUTH_TOKEN", "").strip():
        return True
    path = env.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")
    try:
        return bool(Path(path).read_text().strip())
    except OSError:
        return False


def check_address(address: str, environ: dict | None = None) -> str:
    """The address, if gsgs may connect to it; else GsgsError naming the fix. Nothing is sent first."""
    _, host, _ = split_address(address)
    if not is_loopback(host) and not token_configured(environ):
        raise GsgsError(f"--ray {address}: {host} is not this machine, and no Ray token authentication is set up; "
                        f"a Ray cluster runs whatever its clients send, so gsgs refuses to use one without a token: "
                        f"{HOW_TO_TOKEN}")
    return address.strip()
