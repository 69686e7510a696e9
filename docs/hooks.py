"""mkdocs hook: add the reference pages generated from the installed plugins (sbrdf_core.docgen)."""

from mkdocs.structure.files import File


def on_files(files, config):
    from sbrdf_core.docgen import pages
    from sbrdf_core.registry import default_registry

    for path, text in pages(default_registry()).items():
        files.append(File.generated(config, path, content=text))
    return files
