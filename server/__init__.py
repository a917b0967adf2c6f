"""The ground service (FastAPI + SQLAlchemy). Built by the ground-server issue."""
