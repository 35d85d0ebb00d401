"""Datasets for the learned systems: reproducible from a manifest, made as Ray tasks (or
in this process), streamed into shards that are never rewritten, resumable.

    from tryon.dataset import DrapeDatasetSpec, make_drape_dataset, load_drape_dataset

`tryon dataset drape --garment tshirt --sizes S M L --count 100 --out data/tshirt` makes one.
"""

from tryon.dataset.bodies import BodyRanges, BodySample, sample_body
from tryon.dataset.drapes import DrapeDatasetSpec, split_of
from tryon.dataset.generate import RunReport, open_dataset, run_generator
from tryon.dataset.loading import DrapeDataset, load_drape_dataset, load_drape_datasets, make_drape_dataset
from tryon.dataset.store import DatasetError, Manifest, ShardStore

__all__ = ["BodyRanges", "BodySample", "sample_body", "DrapeDatasetSpec", "split_of", "RunReport", "open_dataset",
           "run_generator", "DrapeDataset", "load_drape_dataset", "load_drape_datasets", "make_drape_dataset", "DatasetError", "Manifest",
           "ShardStore"]
