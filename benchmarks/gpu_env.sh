# Sourced by the GPU scripts (gpu_call.sh, gpu_study.sh) on the device machine: the wheels the GPU
# image lacks (tyro, pydantic: carried in .whl/) installed beside the checkout's src/, and the
# device and its torch and Triton written to $1.
if [ -d .whl ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        && export PYTHONPATH=/tmp/site:src
fi
nvidia-smi -L | tee "$1"
python3 -c "import torch, triton; print(torch.__version__, triton.__version__)" | tee -a "$1"
