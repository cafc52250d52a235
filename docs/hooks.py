"""MkDocs hook: pages that live outside ``docs/`` join the site without a second copy in git.

The pages link to measured results as ``../benchmarks/results/NAME.md`` and to the zoo's model
cards as ``../zoo/NAME/README.md``: paths relative to ``docs/`` that also work when browsing the
repository. This hook adds those files to the build under the same source paths, so MkDocs
resolves and validates such links like any other (a missing file or heading fails the strict
build), and writes them into the site as ``results/...`` and ``model-zoo/...``.
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File, Files, InclusionLevel

#: folder of the repository -> folder of the site, and the file kinds taken from it
EXTERNAL = {
    "benchmarks/results": ("results", (".md", ".png", ".jpg", ".svg", ".json")),
    "zoo": ("model-zoo", (".md", ".png", ".jpg", ".svg")),
}


def on_files(files: Files, config) -> Files:
    root = Path(config["docs_dir"]).resolve().parent
    for folder, (site_folder, suffixes) in EXTERNAL.items():
        base = root / folder
        for path in sorted(base.rglob("*")):
            if not path.is_file() or path.suffix.lower() not in suffixes:
                continue
            rel = path.relative_to(base).as_posix()
            # the source path a page in docs/ links with; dot-paths are excluded unless said otherwise
            file = File.generated(config, f"../{folder}/{rel}", abs_src_path=str(path),
                                  inclusion=InclusionLevel.INCLUDED)
            # ... and where it goes in the site (the URL follows the destination)
            file.dest_uri = File(f"{site_folder}/{rel}", None, config["site_dir"],
                                 config["use_directory_urls"]).dest_uri
            files.append(file)
    return files
