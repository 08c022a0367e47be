"""mkdocs hook: the config reference page is generated from jaxform's schema at build
time, so it cannot go stale (jaxform.config imports no JAX)."""

from jaxform.config import describe_schema

MARKER = "{{ config_reference }}"


def on_page_markdown(markdown, page, config, files):
    if MARKER in markdown:
        return markdown.replace(MARKER, describe_schema())
    return markdown
