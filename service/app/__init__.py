"""The application: the ``Service`` that runs the core between its edges (``service.app.service``)."""
