"""The ground service (FastAPI + SQLAlchemy): REST, the link endpoint, the consoles."""
