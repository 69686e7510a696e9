"""mkdocs hook: add the reference pages generated from the installed plugins (sbrdf_core.docgen).

``docs/reference/`` holds a placeholder of each such page, so its links work
where the repository is read rather than the site (it says how to see the
page there); the generated page takes its place in the build.
"""

from mkdocs.structure.files import File


def on_files(files, config):
    from sbrdf_core.docgen import pages
    from sbrdf_core.registry import default_registry

    for path, text in pages(default_registry()).items():
        placeholder = files.get_file_from_path(path)
        if placeholder is not None:
            files.remove(placeholder)
        files.append(File.generated(config, path, content=text))
    return files
