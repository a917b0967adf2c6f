"""The ground service's work, free of HTTP: each function owns its transaction.

Nothing here imports FastAPI, Starlette or the API's error mapping (an import contract in
pyproject.toml says so): a service refuses a request by raising one of its domain errors
(:mod:`server.services.errors`, no HTTP statuses), which :mod:`server.api.errors` maps to
HTTP in one place."""
