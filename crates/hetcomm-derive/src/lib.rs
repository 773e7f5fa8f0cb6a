//! # hetcomm-derive — `#[derive(Message)]`
//!
//! Implements the `hetcomm` `Message` trait for a user type from one attribute:
//!
//! ```ignore
//! use serde::{Deserialize, Serialize};
//! use hetcomm::Message;
//!
//! #[derive(Serialize, Deserialize, Message)]
//! #[message(id = 1)]
//! struct Wheels { left: f64, right: f64 }
//!
//! assert_eq!(Wheels::TYPE, hetcomm::MessageType(1));
//! assert_eq!(Wheels::NAME, "Wheels");
//! ```
//!
//! The derive expands to
//!
//! ```ignore
//! impl ::hetcomm::Message for Wheels {
//!     const TYPE: ::hetcomm::MessageType = ::hetcomm::MessageType(1);
//!     const NAME: &'static str = "Wheels";
//! }
//! ```
//!
//! ## Attribute keys
//!
//! * `id = N` (required): the stable numeric message type id, an integer literal that fits in
//!   a `u32` (an optional `u32` suffix is accepted, other suffixes are refused).
//! * `crate = "path"` (optional): the path through which `Message` and `MessageType` are
//!   reached, `::hetcomm` by default. Crates inside the hetcomm workspace, which do not depend
//!   on the facade, write `crate = "hetcomm_core"`.
//!
//! Generic types are supported: the impl carries the type's generics and where clause
//! unchanged and adds no bounds of its own, so the type itself must state what `Message`
//! needs of its parameters. With serde's derives, write the bounds in the where clause and
//! switch off serde's own deserialize bound (which would otherwise clash with
//! `DeserializeOwned`):
//!
//! ```ignore
//! #[derive(Serialize, Deserialize, Message)]
//! #[message(id = 32)]
//! #[serde(bound(deserialize = ""))]
//! struct Tagged<T>
//! where
//!     T: Serialize + DeserializeOwned + Send + 'static,
//! {
//!     tag: String,
//!     value: T,
//! }
//! ```
//!
//! Mistakes are compile errors pointing at the offending tokens: a missing `#[message]`
//! attribute, a missing `id`, an `id` that is not a `u32` integer literal, an unknown key, a
//! repeated key or attribute, and a `crate` string that is not a path.

use proc_macro::TokenStream;
use proc_macro2::TokenStream as TokenStream2;
use quote::quote;
use syn::{parse_macro_input, DeriveInput, LitInt, LitStr, Path};

/// Derives the `hetcomm` `Message` trait: `#[message(id = N)]` gives the stable numeric type id
/// and the type's own name becomes `Message::NAME`; `#[message(crate = "path")]` overrides the
/// `::hetcomm` path the impl names.
#[proc_macro_derive(Message, attributes(message))]
pub fn derive_message(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    expand(&input)
        .unwrap_or_else(syn::Error::into_compile_error)
        .into()
}

/// What the `#[message(...)]` attributes of one type say.
struct MessageArgs {
    id: u32,
    krate: Path,
}

fn expand(input: &DeriveInput) -> syn::Result<TokenStream2> {
    let args = parse_args(input)?;
    let ident = &input.ident;
    let name = LitStr::new(&ident.to_string(), ident.span());
    let krate = &args.krate;
    let id = args.id;
    let (impl_generics, ty_generics, where_clause) = input.generics.split_for_impl();
    Ok(quote! {
        #[automatically_derived]
        impl #impl_generics #krate::Message for #ident #ty_generics #where_clause {
            const TYPE: #krate::MessageType = #krate::MessageType(#id);
            const NAME: &'static str = #name;
        }
    })
}

fn parse_args(input: &DeriveInput) -> syn::Result<MessageArgs> {
    let mut id: Option<u32> = None;
    let mut krate: Option<Path> = None;
    let mut seen_attr: Option<&syn::Attribute> = None;

    for attr in input.attrs.iter().filter(|a| a.path().is_ident("message")) {
        if seen_attr.is_some() {
            return Err(syn::Error::new_spanned(
                attr,
                "duplicate `#[message(...)]` attribute: put `id` (and `crate`) in one attribute",
            ));
        }
        seen_attr = Some(attr);
        attr.parse_nested_meta(|meta| {
            if meta.path.is_ident("id") {
                if id.is_some() {
                    return Err(meta.error("duplicate `id` key in `#[message(...)]`"));
                }
                let expr: syn::Expr = meta.value()?.parse()?;
                id = Some(parse_id(&expr)?);
                Ok(())
            } else if meta.path.is_ident("crate") {
                if krate.is_some() {
                    return Err(meta.error("duplicate `crate` key in `#[message(...)]`"));
                }
                let lit: LitStr = meta.value()?.parse().map_err(|e| {
                    syn::Error::new(
                        e.span(),
                        "`crate` takes a string literal path, e.g. `crate = \"hetcomm_core\"`",
                    )
                })?;
                krate = Some(lit.parse::<Path>().map_err(|_| {
                    syn::Error::new(lit.span(), format!("`{}` is not a valid path", lit.value()))
                })?);
                Ok(())
            } else {
                let path = &meta.path;
                let key = quote!(#path).to_string().replace(' ', "");
                Err(meta.error(format!(
                    "unknown key `{key}` in `#[message(...)]`: expected `id = N` or `crate = \"path\"`"
                )))
            }
        })?;
    }

    let Some(attr) = seen_attr else {
        return Err(syn::Error::new(
            input.ident.span(),
            format!(
                "`#[derive(Message)]` needs a message type id: add `#[message(id = N)]` to `{}`",
                input.ident
            ),
        ));
    };
    let Some(id) = id else {
        return Err(syn::Error::new_spanned(
            attr,
            "missing `id` in `#[message(...)]`: write `#[message(id = N)]` with N a u32 literal",
        ));
    };
    let krate = krate.unwrap_or_else(|| syn::parse_quote!(::hetcomm));
    Ok(MessageArgs { id, krate })
}

/// Accepts an unsuffixed (or `u32`-suffixed) integer literal that fits in a `u32`.
fn parse_id(expr: &syn::Expr) -> syn::Result<u32> {
    let lit: &LitInt = match expr {
        syn::Expr::Lit(syn::ExprLit {
            lit: syn::Lit::Int(lit),
            ..
        }) => lit,
        syn::Expr::Group(group) => return parse_id(&group.expr),
        other => {
            return Err(syn::Error::new_spanned(
                other,
                "`id` must be an integer literal that fits in a u32, e.g. `id = 7`",
            ))
        }
    };
    match lit.suffix() {
        "" | "u32" => {}
        suffix => {
            return Err(syn::Error::new(
                lit.span(),
                format!("`id` is a u32: drop the `{suffix}` suffix"),
            ))
        }
    }
    lit.base10_parse::<u32>().map_err(|_| {
        syn::Error::new(
            lit.span(),
            format!(
                "`id` {} does not fit in a u32 (0..=4294967295)",
                lit.base10_digits()
            ),
        )
    })
}
