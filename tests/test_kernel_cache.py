"""The compiled kernels' cache: what _jit invalidates when a kernel module changes."""


def test_a_cache_root_holds_this_checkouts_kernels_in_numbas_folders(tmp_path):
    """_jit._cache_files finds the package's kernels (both source folders) under a cache root
    such as NUMBA_CACHE_DIR in the folders numba's own locator names, and nothing else."""
    import os
    from numba.core.caching import _CacheLocator

    from implicit_contact import _jit

    package = os.path.dirname(os.path.abspath(_jit.__file__))
    ours = [_CacheLocator.get_suitable_cache_subpath(os.path.join(package, "ncp.py")),
            _CacheLocator.get_suitable_cache_subpath(os.path.join(package, "rows", "contact.py"))]
    other = _CacheLocator.get_suitable_cache_subpath(os.path.join(str(tmp_path), "elsewhere", "mod.py"))
    want = []
    for sub in ours + [other]:
        os.makedirs(tmp_path / sub)
        for name in ("k-1.py311.nbi", "k-1.py311.1.nbc"):
            (tmp_path / sub / name).write_text("")
            if sub != other:
                want.append(str(tmp_path / sub / name))
    assert ours[1].startswith("rows_")          # the folder the old filter missed
    assert sorted(_jit._cache_files(str(tmp_path))) == sorted(want)
