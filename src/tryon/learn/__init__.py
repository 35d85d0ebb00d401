"""Learned draping: a network that drapes a garment on a body in milliseconds, trained on
drape datasets (`tryon.dataset`).

    tryon train drape --data DATASET --out MODEL_DIR
    tryon drape ... --method learned

`topology` builds the garment's mesh hierarchy, `features` the body region and the
skinned prior, `network` the model, `losses` its training loss, `data` the training
tensors, `train` the training loop and model card, `model` the model file.
"""
