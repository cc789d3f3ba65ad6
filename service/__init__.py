"""The REST API (FastAPI). Importing this package is light; the app lives in ``service.app``."""
