"""A device URL, parsed (drivers.registry chooses the backend by its scheme):
`scheme://host:port/path?option=value`; `location` is the host for network schemes, the path
for files (`tracker+file://targets.csv` is a relative path)."""

from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import parse_qsl, unquote, urlsplit

from drivers.errors import DeviceConfigError


@dataclass(frozen=True)
class DeviceUrl:
    """A parsed device URL. ``location`` is host for network schemes, the path for files."""

    raw: str
    scheme: str
    host: str = ""
    port: int | None = None
    path: str = ""
    query: dict[str, str] = field(default_factory=dict)

    @property
    def location(self) -> str:
        return self.path or self.host

    def option(self, name: str, default: str) -> str:
        return self.query.get(name, default)

    def number(self, name: str, default: float) -> float:
        try:
            return float(self.query.get(name, default))
        except ValueError as exc:
            raise DeviceConfigError(f"{self.raw}: option {name!r} must be a number") from exc

    def flag(self, name: str, default: bool = False) -> bool:
        """A yes/no option: 1, true, yes, on or 0, false, no, off (DeviceConfigError else)."""
        text = self.query.get(name)
        if text is None:
            return default
        value = {"1": True, "true": True, "yes": True, "on": True, "": True}.get(text.lower())
        if value is None and text.lower() not in ("0", "false", "no", "off"):
            raise DeviceConfigError(f"{self.raw}: option {name!r} must be 1 or 0, got {text!r}")
        return bool(value)

    def address(self, default_port: int) -> tuple[str, int]:
        if not self.host:
            raise DeviceConfigError(f"{self.raw}: no host")
        return self.host, self.port if self.port is not None else default_port


def parse_url(url: str) -> DeviceUrl:
    """Split a device URL; DeviceConfigError if it is not one."""
    if not isinstance(url, str) or "://" not in url:
        raise DeviceConfigError(f"not a device URL: {url!r} (expected scheme://...)")
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError as exc:
        raise DeviceConfigError(f"{url}: bad port") from exc
    scheme = parts.scheme.lower()
    host = unquote(parts.hostname or "") if scheme != "aravis" else unquote(parts.netloc)
    path = unquote(parts.path)
    if scheme.endswith("+file"):  # tracker+file://targets.csv is a relative path
        host, path = "", unquote(parts.netloc) + path
    query = dict(parse_qsl(parts.query, keep_blank_values=True))
    return DeviceUrl(url, scheme, host, port, path, query)
