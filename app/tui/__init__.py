"""The operator's terminal (`rvis tui`): a Textual client of the in-line service. It talks to
the service through its control socket and reads history from its database read-only; it
never owns a device, and closing it never stops the service."""
