# Relight any video (config relight): ingest -> Phi (the configured backend) -> the target lighting ->
# R (Mitsuba) -> the trained refiner with overlap-fused tiling for any length. One command:
#   snakemake relight --cores 2 --config relight='{video: clip.mp4, hdri: sky.exr, rotation_deg: 90}'
# Outputs in results/relight/NAME/: input/ (the video's frames), clip/ (Phi's buffers), lighting.json,
# proxy/, relit/ (linear EXR), relit.mp4, side_by_side.mp4 and strip.png (input | proxy | relit).


rule relight_ingest:
    output:
        video=relight_dir("input.json") if config["relight"]["video"] else [],
    log:
        "logs/relight/ingest.log",
    conda:
        "../../envs/recon.yaml"
    params:
        **script_params("ingest_video.py"),
        clip=lambda wc: params_file(relight_clip()),
        name=lambda wc: relight_name(),
        out_dir=lambda wc, output: str(Path(output.video).with_suffix("")),
        num_frames=lambda wc: relight_clip()["num_frames"],
        w=config["scenes"]["width"],
        h=config["scenes"]["height"],
    shell:
        "python {params.script} --clip-json {params.clip} --clip-id {params.name} --out {params.out_dir} "
        "--width {params.w} --height {params.h} --num-frames {params.num_frames} --short-clips error > {log} 2>&1"


rule relight_reconstruct:
    input:
        video=relight_dir("input.json") if config["relight"]["video"] else [],
        estimator=relight_estimator,
    output:
        clip=relight_dir("clip", "buffers.json") if config["relight"]["video"] else [],
    log:
        "logs/relight/reconstruct.log",
    conda:
        "../../envs/recon.yaml"
    params:
        **script_params("reconstruct.py"),
        backend=recon_backend_args(),
        estimator=estimator_arg,
        out_dir=parent_dir,
        name=lambda wc: relight_name(),
        static=int(config["relight"]["scene_static"]),
        settings=lambda wc: params_file(
            recon_settings()
            if PAPER_STACK
            else dict(
                recon_settings(),
                fov_x_deg=config["relight"]["fov_x_deg"]
                or config["scenes"]["fov_x_deg"],
                camera="static" if config["relight"]["camera_static"] else "auto",
            )
        ),
    shell:
        "python {params.script} --frames {input.video} --out {params.out_dir} {params.backend} {params.estimator} "
        "--scene-static {params.static} --settings-json {params.settings} --name {params.name} > {log} 2>&1"


rule relight_lighting:
    output:
        lighting=relight_dir("lighting.json") if config["relight"]["video"] else [],
    log:
        "logs/relight/lighting.log",
    conda:
        "../../envs/recon.yaml"
    params:
        **script_params("relight_lighting.py"),
        settings=lambda wc: params_file(
            {
                k: config["relight"][k]
                for k in (
                    "hdri",
                    "rotation_deg",
                    "strength",
                    "point_lights",
                    "area_lights",
                )
            }
        ),
    shell:
        "python {params.script} --settings-json {params.settings} --out {output.lighting} > {log} 2>&1"


rule relight_proxy:
    input:
        clip=relight_dir("clip", "buffers.json") if config["relight"]["video"] else [],
        lighting=relight_dir("lighting.json") if config["relight"]["video"] else [],
    output:
        proxy=relight_dir("proxy.json") if config["relight"]["video"] else [],
    log:
        "logs/relight/proxy.log",
    conda:
        "../../envs/mitsuba.yaml"
    threads: 2
    params:
        **script_params("render_proxy.py"),
        clip=clip_dir_of_input,
        out_dir=lambda wc, output: str(Path(output.proxy).with_suffix("")),
        proxy=proxy_settings(),
    shell:
        "python {params.script} --clip {params.clip} --lighting {input.lighting} --out {params.out_dir} "
        "--proxy {params.proxy} --threads {threads} > {log} 2>&1"


rule relight_refine:
    input:
        model=relight_model() if config["relight"]["video"] else [],
        proxy=relight_dir("proxy.json") if config["relight"]["video"] else [],
        video=relight_dir("input.json") if config["relight"]["video"] else [],
        prompt=refiner_prompt_input(),
    output:
        relit=relight_dir("relit.json") if config["relight"]["video"] else [],
    log:
        "logs/relight/refine.log",
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    params:
        **script_params("refine_clip.py"),
        proxy=lambda wc, input: str(Path(input.proxy).with_suffix("")),
        original=lambda wc, input: str(Path(input.video).with_suffix("")),
        out_dir=lambda wc, output: str(Path(output.relit).with_suffix("")),
        cfg=lambda wc: params_file(
            {
                "infer": {"pad_frames": "repeat_last"},
                "device": config["refiner"]["device"],
            }
        ),
    shell:
        "python {params.script} --model {input.model} --proxy {params.proxy} --out {params.out_dir} "
        "--strip-with {params.original} --strip-labels input --out-label relit --config-json {params.cfg} --threads {threads} > {log} 2>&1"


rule relight:
    input:
        lambda wc: relight_dir("relit.json"),
