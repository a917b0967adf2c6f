# The operator console's static build (web/dist): Node only at build time.
FROM node:20-bookworm-slim AS web
WORKDIR /web
COPY web/package.json web/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error
COPY web ./
RUN npm run build

FROM python:3.11-slim
WORKDIR /app
COPY requirements.lock pyproject.toml README.md ./
COPY planner planner
COPY mission mission
COPY spacecraft spacecraft
COPY telemetry telemetry
COPY server server
COPY hikoboshi hikoboshi
# The robot descriptions (ETS-VII and Orihime) and the missions: planner.description and
# mission find them here.
COPY examples examples
# Editable, as scripts/setup.sh does: the server finds the console at /app/web/dist.
RUN pip install --no-cache-dir -r requirements.lock && pip install --no-cache-dir --no-deps -e .
COPY --from=web /web/dist web/dist
RUN mkdir -p web/dist/model && hikoboshi model urdf > web/dist/model/ets7.urdf
ENTRYPOINT ["hikoboshi"]
