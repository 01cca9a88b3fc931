"""An importable work function for the batch-engine tests (process pools and Dask need one)."""
import time

from morphable.errors import InputError


def work(item, folder, options):
    time.sleep(options.get("sleep", 0))
    if item.id in options.get("fail", ()):
        raise InputError(f"{item.images[0]}: made to fail")
    (folder / "out.txt").write_text(" ".join(item.images))
    return {"n_images": len(item.images)}


if __name__ == "__main__":
    import sys

    from morphable.batch import read_manifest, run_batch

    run_batch(read_manifest(sys.argv[1]), sys.argv[2], work, {"sleep": float(sys.argv[3])},
              progress=False)
