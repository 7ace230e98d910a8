"""The service's I/O edges: MAVLink (link, dialect, signing, telemetry decoding), Zenoh, the MCAP
recorder, the restart snapshot and the message encodings they share. Each connection is owned by
one context manager."""
