# The mebm service image (also runs the simulated controller in docker-compose.yml).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    MEBM_DATA_DIR=/data MEBM_HOST=0.0.0.0 MEBM_PORT=8000 MPLCONFIGDIR=/tmp/matplotlib \
    NUMBA_CACHE_DIR=/tmp/numba

WORKDIR /app
# Dependencies first, in their own layer: a code change does not reinstall them. The
# list is read from pyproject.toml, so it cannot drift from what the package declares.
COPY pyproject.toml ./
RUN python -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" \
        > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt \
    && useradd --system --uid 10001 --home /data mebm \
    && mkdir -p /data && chown mebm /data
COPY README.md alembic.ini ./
COPY core ./core
COPY acquisition ./acquisition
COPY storage ./storage
COPY api ./api
# Editable install without dependencies (installed above): the Alembic scripts
# (storage/migrations) are used from the source tree.
RUN pip install --no-deps -e .

USER mebm
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s \
    CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"
CMD ["mebm", "serve"]
