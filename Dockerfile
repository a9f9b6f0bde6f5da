# TCMS-DAQ: one image for both compose services (the service `tcms serve` and the instrument simulators
# `tcms sim serve`). Build: docker compose build
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    TCMS_DATA_DIR=/data

WORKDIR /app
COPY pyproject.toml README.md ./
COPY tcms_daq ./tcms_daq
COPY drivers ./drivers
COPY sim ./sim
COPY config ./config
# the default configs are package data (config/, installed as tcms_daq.defaults): `--config bench-compose.toml` finds them by name
# [plant]: the compose plant's benches share PostgreSQL (and may serve OPC UA)
RUN pip install --no-compile '.[plant]' \
    && useradd --create-home --uid 1000 tcms \
    && mkdir -p /data \
    && chown tcms /data

USER tcms
VOLUME ["/data"]
EXPOSE 8000
CMD ["tcms", "serve", "--host", "0.0.0.0", "--port", "8000", "--data-dir", "/data"]
