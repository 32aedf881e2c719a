"""World models: tokenizer, EMMA-LWM and baselines, training, evaluation and imagination."""
