"""The ground service's work, free of FastAPI: each function owns its transaction."""
