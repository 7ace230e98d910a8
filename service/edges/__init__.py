"""The service's I/O edges: MAVLink (link, dialect, signing, telemetry decoding), Zenoh, the MCAP
recorder, the Foxglove messages it records (``foxglove_scene``, pure builders) and the live
Foxglove view mirroring it (``foxglove_live``), the restart snapshot and the message encodings
they share. Each connection is owned by one context manager."""
