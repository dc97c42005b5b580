# The project and its tests, as the README's two commands run them.
FROM python:3.11-slim

ENV PIP_NO_CACHE_DIR=1 PYTHONUNBUFFERED=1
WORKDIR /opt/tamedpuma

# PyTorch's CPU build first, so the project's torch requirement does not pull a CUDA build.
RUN pip install "torch==2.13.0" --index-url https://download.pytorch.org/whl/cpu

COPY . .
RUN pip install -e ".[dev]" && python -m tamedpuma.sweep recorder=mcap

CMD ["pytest", "-q"]
