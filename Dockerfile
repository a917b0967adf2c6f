# The ground service's image: the console built on a supported Node LTS, then Python with
# the locked dependencies in their own layer (a code change reuses it), then hikoboshi
# installed as a wheel that carries the console, the shipped robots and missions
# (setup.py), run as an unprivileged user. docker-compose.yml runs it; docs/operations.md
# "Containers".

# The operator console's static build (web/dist): Node only at build time.
FROM node:22-bookworm-slim AS web
WORKDIR /web
COPY web/package.json web/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error
COPY web ./
RUN npm run build

FROM python:3.11-slim
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
# The dependencies first, from the lock alone: rebuilt only when the lock changes.
COPY requirements.lock /tmp/requirements.lock
RUN pip install -r /tmp/requirements.lock && rm /tmp/requirements.lock
# Then the source, built into a wheel and installed; the source does not stay in the image.
WORKDIR /src
COPY pyproject.toml setup.py README.md LICENSE ./
COPY planner planner
COPY mission mission
COPY spacecraft spacecraft
COPY telemetry telemetry
COPY server server
COPY hikoboshi hikoboshi
COPY examples examples
COPY --from=web /web/dist web/dist
# The 3D view's model beside the console (as web/build.mjs writes it in a checkout).
RUN mkdir -p web/dist/model \
    && python -m hikoboshi model urdf > web/dist/model/ets7.urdf \
    && pip install --no-deps . \
    && cd / && rm -rf /src
# An unprivileged user owning only its data directory (a volume in docker-compose.yml):
# SQLite when no DATABASE_URL is given, the stored recordings and reports.
RUN useradd --system --uid 10001 --user-group --home-dir /var/lib/hikoboshi --create-home \
        hikoboshi \
    && mkdir -p /var/lib/hikoboshi/data && chown hikoboshi:hikoboshi /var/lib/hikoboshi/data
WORKDIR /var/lib/hikoboshi
ENV HIKOBOSHI_DATA_DIR=/var/lib/hikoboshi/data
USER hikoboshi
ENTRYPOINT ["hikoboshi"]
