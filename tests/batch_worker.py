"""An importable work function for the batch-engine tests (process pools and Dask need one)."""
import sys
import time

from morphable.errors import InputError


def work(item, folder, options):
    time.sleep(options.get("sleep", 0))
    if item.id in options.get("fail", ()):
        raise InputError(f"{item.images[0]}: made to fail")
    (folder / "out.txt").write_text(" ".join(item.images))
    return {"n_images": len(item.images)}


def main(argv) -> int:
    """``batch_worker FOLDER OUT``: :func:`work` over the images of FOLDER into OUT."""
    from morphable.batch import read_manifest, run_batch

    run_batch(read_manifest(argv[0]), argv[1], work, progress=False)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
