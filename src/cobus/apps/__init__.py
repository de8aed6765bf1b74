"""User-facing programs built on the public API: demo, monitor, gateway, operator panel."""
