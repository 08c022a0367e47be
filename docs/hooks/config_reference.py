"""mkdocs hook: the config reference page is generated from jaxform's schema at build
time, so it cannot go stale (jaxform.config imports no JAX)."""

from jaxform.config import describe_schema
from jaxform.process_config import describe_process_schema

MARKER = "{{ config_reference }}"


def on_page_markdown(markdown, page, config, files):
    if MARKER in markdown:
        return markdown.replace(MARKER, describe_schema() + "\n\n" + describe_process_schema())
    return markdown
