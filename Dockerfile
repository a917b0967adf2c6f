FROM python:3.11-slim
WORKDIR /app
COPY requirements.lock pyproject.toml README.md ./
COPY planner planner
COPY spacecraft spacecraft
COPY telemetry telemetry
COPY server server
COPY hikoboshi hikoboshi
RUN pip install --no-cache-dir -r requirements.lock && pip install --no-cache-dir --no-deps .
ENTRYPOINT ["hikoboshi"]
