# Scene edits on the relighting path (lightcrafter.editing): light insertion, a material edit, an object
# insertion on the reconstructed scene of one test clip; each rendered by R and refined by the same
# trained model (no retraining).


rule edit_scene:
    input:
        clip=L.aligned_clip_manifest(EDIT["scene"], EDIT["traj"]),
        scene=L.scene_spec(EDIT["scene"]),
        manifest=L.assets_manifest(),
    output:
        record=L.edit_record("{kind}"),
    log:
        "logs/edits/{kind}.log",
    benchmark:
        "logs/benchmark/edits/{kind}.tsv"
    conda:
        "../../envs/mitsuba.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=20,
    params:
        **script_params("edit_scene.py"),
        clip=clip_dir_of_input,
        out_dir=parent_dir,
        traj=EDIT["traj"],
        light=EDIT["light"],
        settings=edit_settings,
    shell:
        "python {params.script} --kind {wildcards.kind} --clip {params.clip} --scene {input.scene} "
        "--traj {params.traj} --light {params.light} --out {params.out_dir} "
        "--settings-json {params.settings} --manifest {input.manifest} > {log} 2>&1"


rule render_edit:
    input:
        record=L.edit_record("{kind}"),
        clip=L.aligned_clip_manifest(EDIT["scene"], EDIT["traj"]),
    output:
        L.edit_proxy("{kind}") + ".json",
    log:
        "logs/edits/render_{kind}.log",
    benchmark:
        "logs/benchmark/edits/render_{kind}.tsv"
    conda:
        "../../envs/mitsuba.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=20,
    params:
        **script_params("render_proxy.py"),
        clip=edit_render_clip,
        lighting=lambda wc: L.edit_lighting(wc.kind),
        out_dir=manifest_stem,
        proxy=proxy_settings(),
    shell:
        "python {params.script} --clip {params.clip} --lighting {params.lighting} --out {params.out_dir} "
        "--proxy {params.proxy} --threads {threads} > {log} 2>&1"


rule refine_edit:
    input:
        model=L.refiner_model(EDIT["variant"]),
        proxy=L.edit_proxy("{kind}") + ".json",
        original=L.proxy(EDIT["scene"], EDIT["traj"], EDIT["light"]) + ".json",
    output:
        L.edit_refined("{kind}") + ".json",
    log:
        "logs/edits/refine_{kind}.log",
    benchmark:
        "logs/benchmark/edits/refine_{kind}.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        **script_params("refine_clip.py"),
        proxy=lambda wc, input: str(Path(input.proxy).with_suffix("")),
        original=lambda wc, input: str(Path(input.original).with_suffix("")),
        out_dir=manifest_stem,
    shell:
        "python {params.script} --model {input.model} --proxy {params.proxy} --out {params.out_dir} "
        "--strip-with {params.original} --threads {threads} > {log} 2>&1"
