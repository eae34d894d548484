# The mebm service image (also runs the simulated controller in docker-compose.yml).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    MEBM_DATA_DIR=/data MEBM_HOST=0.0.0.0 MEBM_PORT=8000 MPLCONFIGDIR=/tmp/matplotlib \
    NUMBA_CACHE_DIR=/tmp/numba

WORKDIR /app
COPY pyproject.toml README.md alembic.ini ./
COPY core ./core
COPY acquisition ./acquisition
COPY storage ./storage
COPY api ./api
# Editable install: the Alembic scripts (storage/migrations) are used from the source tree.
RUN pip install -e . \
    && useradd --system --uid 10001 --home /data mebm \
    && mkdir -p /data && chown mebm /data

USER mebm
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s \
    CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"
CMD ["mebm", "serve"]
